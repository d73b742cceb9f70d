"""Ray casting on encrypted bricks, as a MapReduce on Dask, and its plaintext reference.

The data path of one frame, module by module:

=================  =============================================================
``camera``         :class:`Camera`: the request's geometry (frozen, validated)
``views``          anatomical presets of ``Camera.orbit(view=...)`` (RAS+ patient frame)
``plane``          :class:`Plane`: a slice (and slab) as the second kind of view
``modes``          ``RenderSpec``: mode, sampling, channels, combination matrix
``request``        a request checked once where it enters; a view moved to a pyramid level
``rays``           rays, slab tests and sample positions
``weights``        per-brick sparse (ray, voxel, weight) matrices
``planner``        overflow planning: fixed-point digits, packing bounds
``kernel``         the per-brick multi-exponentiation (cost model in its docstring)
``graph``          the Dask graph: map per brick, tree merge per tile
``finishing``      combination, normalisation and packing of one tile (or of the sums only)
``encrypted``      ``render`` (client or server finishing), the ray-sum cache
``bounds``         ``error_bound``: a decrypted pixel against ``render_plain``
``stream``         ``render_frame``: finishing units decrypted on the client as they complete
``slices``         ``render_slice``: slices through the same pipeline
``sums``           ray sums kept in memory or in a ``.hevrsums`` file; ``recolour``
``plain``          ``render_plain`` / ``render_slice_plain``: the independent plaintext references
=================  =============================================================

(The package is named ``rendering`` so that it does not shadow the :func:`hevr.render`
function.)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr._lazy)
    from .camera import Camera
    from .encrypted import RaySums, clear_cache, error_bound, render
    from .plain import render_plain, render_slice_plain
    from .plane import Plane
    from .slices import render_slice
    from .sums import SavedSums, load_sums, recolour

__all__ = ["Camera", "Plane", "RaySums", "SavedSums", "clear_cache", "error_bound", "load_sums", "recolour", "render",
           "render_plain", "render_slice", "render_slice_plain"]

# Name -> submodule, imported on first use: ``hevr.rendering.views`` or ``.camera`` alone (the
# command line's --view choices) need numpy, not Dask. Equal to the TYPE_CHECKING imports above.
_LAZY = {
    ".camera": ("Camera",),
    ".encrypted": ("RaySums", "clear_cache", "error_bound", "render"),
    ".plain": ("render_plain", "render_slice_plain"),
    ".plane": ("Plane",),
    ".slices": ("render_slice",),
    ".sums": ("SavedSums", "load_sums", "recolour"),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
