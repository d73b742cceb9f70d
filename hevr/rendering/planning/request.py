"""A render request, checked once where it enters (:func:`hevr.render`, :func:`hevr.render_slice`,
:func:`hevr.render_frame`, :func:`hevr.error_bound`), and the view moved to a pyramid level.

The checked :class:`~hevr.rendering.planning.modes.RenderSpec` is passed inward; nothing below asks
the user's arguments again.

**Cost.** What a request costs, from public parameters alone, before any work (:func:`request_cost`).

``hevr serve`` refuses a request whose cost is above its budget (:mod:`hevr.serve.budget`); the
unit is one *product*: a (ciphertext, public weight) pair of 10-bit weights or fewer that the map
kernel multiplies into a ray's accumulator (:mod:`hevr.rendering.pipeline.kernel`; a nearest pair
is one modular multiplication mod n², a trilinear pair of 10-bit weights about 2.4 after the
kernel's bucketing).

A per-voxel store, a view (camera or plane) at pyramid level L:

.. math::

    P = \\left\\lceil C \\cdot c \\cdot \\sum_r n_r \\cdot \\max(b, 10) / 10 \\right\\rceil

with n_r the samples of ray r (:func:`~hevr.rendering.geometry.rays.cast_rays` at ``step·2^L``
through level L's voxel-centre box; a plane's pixel: its slab), c the voxels one sample reads
(nearest 1, trilinear 8), C the ciphertexts per voxel of the channel (scalar 1, vector and
gradient their ``dims``) and b the bits of a weight (:func:`weight_bits`: trilinear ``digits``
d give weights up to 10^d + 4, b = 10 at the default d = 3 and 30 at d = 9; nearest 1). The
kernel's windows grow with b: measured with its operation counter (rows of 128 pairs, random
b-bit weights), a pair costs 1.0, 2.3, 3.6, 4.2 and 5.8 multiplications at b = 3, 10, 16, 20
and 30, so max(b, 10)/10 bounds the ratio to 10-bit pairs (1.6, 1.9, 2.6 measured at 16, 20,
30 bits). The kernel merges the pairs of a voxel that consecutive samples share, so P bounds
the work from above. A packed store takes one sample per slice, at most N = max(nz, ny, nx) of
them, and bilinear sampling in the slice reads 4 voxels (c = 1 or 4), b its ``weight_bits``
(the request's, else the store's; nearest 1): P = ⌈C·c·R·N·max(b, 10)/10⌉ for R pixels, again
an upper bound (one packed product serves S rays).

Counting casts the rays (time linear in the pixels, memory of a few MB: :data:`COUNT_CHUNK` rays at
a time), so the server bounds the pixels first. A 512² frame through a 512×512×300 CT (unit spacing, step 1),
trilinear, the vector channel's 4 components (the viewer's emphasis): at the viewer's orbit
(azimuth 30°, elevation 20°) 2.90·10^7 samples, P = 9.29·10^8; with every ray as long as the
box's diagonal (785 samples) P = 512²·785·8·4 = 6.58·10^9.

>>> from hevr.rendering.geometry.camera import Camera
>>> cam = Camera.orbit((300, 512, 512), azimuth=30, elevation=20, width=512, height=512)
>>> c = ray_cost(cam, (300, 512, 512), (1, 1, 1), 1.0, "trilinear", 4)
>>> c.rays, c.samples, c.products
(262144, 29028505, 928912160)
>>> c.describe()
'512x512 rays, 2.9e+07 samples, 8 voxels a sample, 4 ciphertexts a voxel'
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from ...core.validate import check_choice, check_int, check_shape
from ...errors import ParameterError
from ...image.checks import FINISHES
from ...store.reader import EncryptedVolume
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from ..geometry.rays import cast_rays
from .modes import RenderSpec, make_spec

__all__ = [
    "FINISHES",
    "RenderCost",
    "at_level",
    "check_request",
    "level_step",
    "ray_cost",
    "request_cost",
    "weight_bits",
    "weighted",
]


def check_request(
    ev: Any,
    camera: Any,
    mode: Any,
    sampling: Any,
    step: Any,
    density: Any,
    nodes: Any,
    digits: Any,
    precision: Any,
    comb_digits: Any,
    views: tuple[type, ...] = (Camera,),
    gradient: Any = False,
    finish: Any = "client",
) -> tuple[RenderSpec, int, int, int]:
    """Check what :func:`render` and :func:`error_bound` share, once, where it enters (``views``:
    the kinds of view the caller takes)."""
    if not isinstance(ev, EncryptedVolume):
        raise ParameterError(f"ev: expected an EncryptedVolume (hevr.open_volume), got {type(ev).__name__}")
    if not isinstance(camera, views):
        kinds = " or ".join(f"hevr.{v.__name__}" for v in views)
        raise ParameterError(f"camera: expected a {kinds}, got {type(camera).__name__}")
    spec = make_spec(mode, sampling, step, density, nodes, ev.vector_dims, ev.has_scalar, gradient, ev.has_gradient)
    check_choice("finish", finish, FINISHES)
    return (
        spec,
        check_int("digits", digits, 0, 9),
        check_int("precision", precision, 0, 30),
        check_int("comb_digits", comb_digits, 1, 12),
    )


def at_level(ev: EncryptedVolume, view: Camera | Plane, level: int | None) -> tuple[EncryptedVolume, Camera | Plane]:
    """The volume to render — ``ev``, or the pyramid level asked for — and the view moved into
    that level's frame: a level's voxel (0, 0, 0) sits at ``ev.origin``, hevr's rays assume
    the origin, so the view moves by ``−origin`` (an exact change of coordinates)."""
    if level is not None and level != ev.level:
        ev = ev.at_level(level)
    if not ev.level:
        return ev, view
    shift = np.asarray(ev.origin)
    if isinstance(view, Plane):
        return ev, dataclasses.replace(view, origin=tuple((np.asarray(view.origin) - shift).tolist()))
    return ev, dataclasses.replace(
        view,
        position=tuple((np.asarray(view.position) - shift).tolist()),
        focal_point=tuple((np.asarray(view.focal_point) - shift).tolist()),
    )


def level_step(spec: RenderSpec, ev: EncryptedVolume, view: Camera | Plane) -> RenderSpec:
    """A level is sampled in its own voxels: ``step`` (world units at level 0) becomes
    ``step·2^level``, so a coarse frame takes 2^level times fewer samples per ray instead of
    revisiting each coarse voxel 2^level times (a plane keeps its slab step)."""
    if not ev.level or isinstance(view, Plane):
        return spec
    return dataclasses.replace(spec, step=spec.step * 2**ev.level)


VOXELS_PER_SAMPLE = {"nearest": 1, "trilinear": 8}
PACKED_VOXELS_PER_SAMPLE = {"nearest": 1, "trilinear": 4}  # bilinear within the slice
COUNT_CHUNK = 1 << 16  # rays cast at once to count samples
REFERENCE_BITS = 10  # a product: a pair of weights of this many bits or fewer (module docstring)


def weight_bits(sampling: str, digits: int = 3, packed_bits: int | None = None) -> int:
    """The bits b of a sample's weight: nearest 1; trilinear, a per-voxel store's ``digits`` d
    (weights up to 10^d + 4) or a packed store's ``packed_bits`` (its in-slice weight bits).

    >>> weight_bits("nearest", 9), weight_bits("trilinear", 3), weight_bits("trilinear", 9)
    (1, 10, 30)
    >>> weight_bits("trilinear", packed_bits=16), weight_bits("nearest", packed_bits=16)
    (16, 1)
    """
    if sampling != "trilinear":
        return 1
    if packed_bits is not None:
        return int(packed_bits)
    return (10 ** int(digits) + 4).bit_length()


def weighted(pairs: int, bits: int) -> int:
    """The products of ``pairs`` (ciphertext, weight) pairs of ``bits``-bit weights:
    ⌈pairs · max(bits, 10) / 10⌉ (module docstring).

    >>> weighted(1000, 1), weighted(1000, 10), weighted(1000, 16), weighted(1000, 30), weighted(7, 11)
    (1000, 1000, 1600, 3000, 8)
    """
    return -(-int(pairs) * max(int(bits), REFERENCE_BITS) // REFERENCE_BITS)


class RenderCost(NamedTuple):
    """A render's products ``P = ⌈components · per_sample · samples · max(bits, 10) / 10⌉`` (module
    docstring)."""

    width: int
    height: int
    samples: int  # Σ_r n_r (a packed store: R·N)
    per_sample: int  # c
    components: int  # C
    products: int
    bits: int = 1  # b

    @property
    def rays(self) -> int:
        return self.width * self.height

    def describe(self) -> str:
        """The formula's factors, for a message."""
        return (
            f"{self.width}x{self.height} rays, {self.samples:.2g} samples, {self.per_sample} voxel"
            f"{'s' if self.per_sample > 1 else ''} a sample, {self.components} ciphertext"
            f"{'s' if self.components > 1 else ''} a voxel"
            + (f", {self.bits}-bit weights" if self.bits > REFERENCE_BITS else "")
        )


def ray_cost(
    view: Camera | Plane,
    shape: Any,
    spacing: Any,
    step: float,
    sampling: str,
    components: int,
    packed: bool = False,
    bits: int = 1,
) -> RenderCost:
    """The cost of ``view`` through a volume of ``shape`` (nz, ny, nx) and ``spacing`` at ``step``
    (world units of this volume), ``components`` ciphertexts a voxel, ``bits`` a weight
    (:func:`weight_bits`); ``packed``: a packed store's public bound R·N (module docstring)."""
    w, h = view.width, view.height
    if packed and isinstance(view, Camera):
        samples = w * h * max(check_shape(shape))
        c = PACKED_VOXELS_PER_SAMPLE[sampling]
    else:  # counted COUNT_CHUNK rays at a time: the memory of a few MB, whatever the image
        samples = sum(
            int(
                cast_rays(view, shape, spacing, step, np.arange(a, min(a + COUNT_CHUNK, w * h))).n_samples.sum(
                    dtype=np.float64
                )
            )
            for a in range(0, w * h, COUNT_CHUNK)
        )
        c = VOXELS_PER_SAMPLE[sampling]
    return RenderCost(w, h, samples, c, int(components), weighted(int(components) * c * samples, bits), int(bits))


def request_cost(
    ev: Any,
    view: Camera | Plane,
    channel: str,
    sampling: str,
    step: float,
    level: int | None = None,
    digits: int = 3,
    packed_bits: int | None = None,
) -> RenderCost:
    """The cost of rendering ``channel`` of the store ``ev`` (an opened store: per-voxel or packed)
    as ``view`` at ``level`` (``step`` in level 0's world units, as :func:`hevr.render` takes it),
    trilinear weights of ``digits`` decimal digits (a per-voxel store) or ``packed_bits`` bits (a
    packed store; None: the store's ``weight_bits``)."""
    ev_l, view_l = at_level(ev, view, level or None)
    if isinstance(view_l, Camera) and ev_l.level:
        step = step * 2**ev_l.level  # a level is sampled in its own voxels (level_step)
    info = getattr(ev.meta, channel, None) if channel != "scalar" else None
    components = int(getattr(info, "dims", 1) or 1)
    packing = ev.meta.packing
    if packing is not None and packed_bits is None:
        packed_bits = packing.weight_bits
    bits = weight_bits(sampling, digits, packed_bits if packing is not None else None)
    return ray_cost(view_l, ev_l.shape, ev_l.spacing, step, sampling, components, packing is not None, bits)
