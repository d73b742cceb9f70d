"""Ray casting on encrypted bricks, as a MapReduce on Dask, and its plaintext reference.

The data path of one frame reads from the folder names, room by room:

=================  =============================================================
``geometry/``      camera, views, plane, rays, footprint, weights, group_weights: where
                   the rays go and which voxels each sample reads (plaintext numpy)
``planning/``      modes, request, planner, bounds: the request checked once, every
                   quantity bounded from public parameters before any ciphertext
``pipeline/``      kernel, maps, graph, reduce, finishing, sums, cache, stream: the
                   MapReduce on Dask over ciphertext bricks, its ray sums, the streamed frame
``reference/``     plain: ``render_plain`` / ``render_slice_plain``, the independent
                   plaintext references
``packed/``        request, shear, plan, graph, image, sliced: a packed store's frame
                   (:mod:`hevr.store.packing`), slice by slice, from request to pixels
=================  =============================================================

The entry points stay here, beside the rooms they walk through:

=================  =============================================================
``encrypted``      ``render`` (client or server finishing), the ray-sum cache
``slices``         ``render_slice``: slices through the same pipeline
``view``           the render of one view of a per-voxel store, behind both
``verify``         verified renders: the request, the tags' sums on the server
``verification``   the record of a verified render and the client's check
``tag_betas``      the client's Σρ·B from the public geometry and the tag key
=================  =============================================================

Each room's ``__init__`` names its modules in the order the data flows through them.

(The package is named ``rendering`` so that it does not shadow the :func:`hevr.render`
function.)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..core.lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr.core.lazy)
    from .encrypted import RaySums, clear_cache, error_bound, render
    from .geometry.camera import Camera
    from .geometry.plane import Plane
    from .pipeline.sums import SavedSums, load_sums, recolour
    from .reference.plain import render_plain, render_slice_plain
    from .slices import render_slice

__all__ = [
    "Camera",
    "Plane",
    "RaySums",
    "SavedSums",
    "clear_cache",
    "error_bound",
    "load_sums",
    "recolour",
    "render",
    "render_plain",
    "render_slice",
    "render_slice_plain",
]

# Name -> submodule, imported on first use: ``hevr.rendering.geometry.views`` or ``.camera`` alone
# (the command line's --view choices) need numpy, not Dask. Equal to the TYPE_CHECKING imports above.
_LAZY = {
    ".encrypted": ("RaySums", "clear_cache", "error_bound", "render"),
    ".geometry.camera": ("Camera",),
    ".geometry.plane": ("Plane",),
    ".pipeline.sums": ("SavedSums", "load_sums", "recolour"),
    ".reference.plain": ("render_plain", "render_slice_plain"),
    ".slices": ("render_slice",),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
