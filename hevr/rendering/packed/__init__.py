"""Frames of packed stores (:mod:`hevr.store.packing`): parallel projections sampled slice by slice.

The data path of one packed frame, module by module:

=================  =============================================================
``request``        what a packed store's frame may ask, checked where ``hevr.render`` routes it
``shear``          the view's slices, slopes, intermediate rays and the warp to pixels
``plan``           :class:`SlicePlan`, the frame plan: which pack serves which rays with which
                   weight (accumulators by block, row and class), slot safety, the decoding
``graph``          the Dask graph: map per brick, merge and Horner combine per tile
``image``          :class:`PackedImage`: the key holder's checks, decoding and warp
``sliced``         ``render_plain(..., slices=True)`` and the error bound against it
``planes``         slices (:class:`~hevr.rendering.geometry.plane.Plane`): the plan, the refusals, the bound
``plane_image``    a slice's Dask graph and :class:`PackedSlice`, the key holder's checks and finishing
``verified``       verified frames: the tags' aggregate on the server and the key holder's check
``files``          packed frame files: :meth:`PackedImage.save`, read by ``hevr.load_image``
``colour``         transfer-function and emphasis frames: the vector channel's k components
``colour_render``  a colour frame's render: map, merge and the tags' round of k components
=================  =============================================================

``hevr.render`` routes a packed store to :func:`hevr.rendering.packed.request.render_packed_request`.
"""

from __future__ import annotations

from .image import PackedImage
from .plan import SlicePlan
from .plane_image import PackedSlice
from .shear import ShearGeometry

__all__ = ["PackedImage", "PackedSlice", "ShearGeometry", "SlicePlan"]
