"""The pipeline: the MapReduce on Dask that turns ciphertext bricks into merged, finished ray sums.

The data flows through this room in this order:

=================  =============================================================
``kernel``         the per-brick multi-exponentiation ``prod c^w`` (cost model in its docstring)
``_segments``      the array-API building blocks of the kernel's product plan
``maps``           the map tasks: one brick, or a worker's group of resident bricks
``graph``          the Dask graph: map per brick (or per worker), tree merge per tile
``reduce``         a batched render's reduce: a worker's block of tiles merged and finished
``finishing``      ⊕ of partial sums, combination, normalisation and packing of one tile
``sums``           ray sums kept in memory or read from a file; ``recolour``
``sums_file``      the ``.hevrsums`` file: written beside a render, read back checked
``cache``          the render cache: the ray sums of the last views, per process
``stream``         ``render_frame``: finishing units decrypted on the client as they complete
=================  =============================================================

Before: :mod:`hevr.rendering.geometry` (the weights a map task computes) and
:mod:`hevr.rendering.planning` (the plan it obeys). :func:`hevr.render`
(:mod:`hevr.rendering.encrypted`, :mod:`hevr.rendering.view`) builds and runs this graph.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ...core.lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr.core.lazy)
    from .finishing import finish_tile, merge_partials
    from .graph import build_sums_graph
    from .kernel import brick_ray_products_multi, plan_products
    from .maps import map_brick, map_group
    from .reduce import BlockedReduce
    from .stream import render_frame
    from .sums import RaySums, SavedSums, load_sums, recolour

__all__ = [
    "BlockedReduce",
    "RaySums",
    "SavedSums",
    "brick_ray_products_multi",
    "build_sums_graph",
    "finish_tile",
    "load_sums",
    "map_brick",
    "map_group",
    "merge_partials",
    "plan_products",
    "recolour",
    "render_frame",
]

# Name -> submodule, imported on first use. Equal to the TYPE_CHECKING imports above.
_LAZY = {
    ".finishing": ("finish_tile", "merge_partials"),
    ".graph": ("build_sums_graph",),
    ".kernel": ("brick_ray_products_multi", "plan_products"),
    ".maps": ("map_brick", "map_group"),
    ".reduce": ("BlockedReduce",),
    ".stream": ("render_frame",),
    ".sums": ("RaySums", "SavedSums", "load_sums", "recolour"),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
