"""Geometry: where the rays go and which voxels each sample reads (plaintext numpy, public inputs).

The data flows through this room in this order:

=================  =============================================================
``coordinates``    the world coordinates a view may hold, and the volume it is placed on
``camera``         :class:`Camera`: the request's geometry (frozen, validated)
``views``          anatomical presets of ``Camera.orbit(view=...)`` (RAS+ patient frame)
``plane``          :class:`Plane`: a slice (and slab) as the second kind of view
``plane_grid``     the pixel grids of axial, coronal, sagittal and oblique planes
``rays``           rays of a view, ray/box clipping and sample positions
``footprint``      each brick's image rectangle and tiles (the graph in O(bricks + pixels))
``weights``        one brick's sparse (ray, voxel, weight) matrix (nearest, trilinear)
``group_weights``  nearest weights of a worker's bricks in one pass, a row per ray
=================  =============================================================

Next: :mod:`hevr.rendering.planning` bounds every quantity these weights produce.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ...core.lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr.core.lazy)
    from .camera import Camera
    from .footprint import Footprint, brick_footprints
    from .group_weights import nearest_group_rows
    from .plane import Plane
    from .rays import RaySet, cast_rays
    from .views import VIEWS
    from .weights import BrickWeights, brick_weights

__all__ = [
    "VIEWS",
    "BrickWeights",
    "Camera",
    "Footprint",
    "Plane",
    "RaySet",
    "brick_footprints",
    "brick_weights",
    "cast_rays",
    "nearest_group_rows",
]

# Name -> submodule, imported on first use (``.camera`` alone needs numpy only). Equal to the
# TYPE_CHECKING imports above.
_LAZY = {
    ".camera": ("Camera",),
    ".footprint": ("Footprint", "brick_footprints"),
    ".group_weights": ("nearest_group_rows",),
    ".plane": ("Plane",),
    ".rays": ("RaySet", "cast_rays"),
    ".views": ("VIEWS",),
    ".weights": ("BrickWeights", "brick_weights"),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
