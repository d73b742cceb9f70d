"""Slices (:class:`~hevr.rendering.geometry.plane.Plane`) of a packed store: the public plan.

A packed store (:mod:`hevr.store.packing`) holds, per column A along its packing axis ``a``,
Enc(P[A]) with slot s of P[A] the voxel u[S·A + s] (u = m − offset). A slice pixel averages its
slab samples inside the voxel-centre box (exactly :func:`hevr.render_slice_plain`'s positions and
inside test). Split every sample point p into its ``a`` coordinate p_a and its *footprint*, the
voxels of the other two axes (b, c) it reads with in-slice weights (nearest: the voxel at
floor(p + 0.5), weight 1; ``trilinear``: the 2×2 voxels around it, the bilinear factors' products
rounded to multiples of 1/U, U = 2^weight_bits). For a footprint F with integer weights w_f the
server computes, per pack A the pixels need,

    Enc(V_F[A]) = Π_{f∈F} Enc(P[A, b_f, c_f])^{w_f},     slot s of V_F[A] = Σ_f w_f·u[S·A + s, b_f, c_f],

one ciphertext holding the footprint's value on S consecutive layers. The key holder decrypts it,
checks it (in (0, n²); no bit above its S slots; every slot at most span·Σ_f w_f, and 0 for a
layer past the volume's end) and finishes every pixel in float64 along ``a``:

    value = (1/n) Σ_samples Σ_{L ∈ {L0, L0+1}} α_L·(V_F(L) + offset·W_F)·10^e / U,

α = (1 − f, f) the linear factors along ``a`` at p_a = L0 + f (nearest: the layer floor(p_a + 0.5),
α = 1), n the pixel's samples inside. This is trilinear sampling with the in-slice weights rounded,
so the error against the float64 reference is at most 2V/U per sample (four weights off by at most
1/2U each, V = max |value|) plus a float store's rounding 0.5·10^e·(1 + 2/U)
(:func:`packed_slice_error_bound`); a nearest slice is exact to the store's quantisation.

Which planes share footprints: on a plane *containing* the ``a`` direction whose pixel column runs
along ``a`` (``Plane.coronal`` / ``Plane.sagittal`` of a z-packed store, ``Plane.oblique`` with a
normal perpendicular to ``a``) every pixel of a column has the same footprint, so one ciphertext
serves S pixels; on a plane *perpendicular* to ``a`` (``Plane.axial``) each pixel has its own
footprint and reads one slot (two for a trilinear sample between layers of two packs) of one
ciphertext. Every other plane mixes the layers within a footprint and is refused; a per-voxel store
serves it. Pixels are grouped by footprint exactly (equal voxels and weights), so a plane whose
pixel grid is rotated within it is still served correctly, one footprint per pixel.

>>> from hevr.store.packing import PackingInfo
>>> info = PackingInfo(axis=0, slots=4, slot_bits=24, weight_bits=8, offset=0)
>>> plan = PlanePlan.build(Plane.coronal((10, 3, 5), 1), (10, 3, 5), (1.0, 1.0, 1.0), (4, 3, 5), info, "nearest")
>>> plan.kind, plan.n_footprints, plan.n_values      # 5 columns of 10 pixels, 3 packs each
('contains', 5, 15)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.validate import check_choice, check_int, check_spacing
from ...errors import ParameterError
from ...store.packing import MAX_WEIGHT_BITS, PackingInfo
from ..geometry.plane import Plane
from ..planning.planner import check_render_size
from .shear import AXIS_NAMES

__all__ = ["PlanePlan", "packed_slice_error_bound", "plane_kind"]

_TOL = 1e-9  # |n·e_a| within this of 0 (contains a) or of 1 (perpendicular to a), as Plane's own tolerances
TILE_VALUES = 1024  # output ciphertexts per merge task


def plane_kind(plane: Plane, axis: int) -> str:
    """``"perpendicular"`` or ``"contains"``: how ``plane`` lies to the packing ``axis`` (an array
    axis); :class:`hevr.ParameterError` naming ``plane`` for any other plane.

    >>> plane_kind(Plane.axial((4, 4, 4), 1), 0), plane_kind(Plane.coronal((4, 4, 4), 1), 0)
    ('perpendicular', 'contains')
    """
    n = plane.normal
    dot = abs(float(n[2 - axis]))  # the world component (x, y, z) of array axis ``axis``
    if dot >= 1.0 - _TOL:
        return "perpendicular"
    if dot <= _TOL:
        return "contains"
    name = AXIS_NAMES[axis]
    helpers = {
        0: "Plane.axial, or Plane.coronal / Plane.sagittal",
        1: "Plane.coronal, or Plane.axial / Plane.sagittal",
        2: "Plane.sagittal, or Plane.axial / Plane.coronal",
    }[axis]
    angle = math.degrees(math.acos(min(1.0, dot)))
    raise ParameterError(
        f"plane: expected a plane perpendicular to the packing axis {name} or containing its direction ({helpers}, "
        f"or Plane.oblique with a normal along {name} or perpendicular to it) on a store packed along {name}, got a "
        f"plane whose normal {tuple(round(float(x), 6) for x in n)} is at {angle:.4g} degrees to {name}; a per-voxel "
        "store (encrypt_volume(..., layout='voxel')) serves every plane"
    )


@dataclass(frozen=True, eq=False)
class PlanePlan:
    """One slice of a packed store, planned from public parameters only (module docstring).

    Attributes
    ----------
    plane : Plane
    packing : PackingInfo
    shape, brick : (int, int, int)
        The store's array shape and voxel brick.
    sampling : {"nearest", "trilinear"}
    weight_bits : int
        Bits of the in-slice weights (U = 2^weight_bits; nearest weights are 1).
    kind : {"perpendicular", "contains"}
    fp_id, fp_b, fp_c, fp_w : (E,) int64
        The footprints' voxels, sorted by footprint: footprint id, the voxel along the first and the
        second non-packing array axis, and the integer weight (> 0).
    packs : (F, 2) int64
        Per footprint the packs ``[A_lo, A_hi)`` computed; ``starts`` (F + 1,): its first output value.
    terms : (R,) pixel, value, slot int64 and alpha float64
        The key holder's finishing: pixel += alpha·(slot of value).
    counts : (H·W,) int64
        Samples inside per pixel (``hits``: counts > 0).
    """

    plane: Plane
    packing: PackingInfo
    shape: tuple[int, int, int]
    brick: tuple[int, int, int]
    sampling: str
    weight_bits: int
    kind: str
    fp_id: np.ndarray = field(repr=False)
    fp_b: np.ndarray = field(repr=False)
    fp_c: np.ndarray = field(repr=False)
    fp_w: np.ndarray = field(repr=False)
    packs: np.ndarray = field(repr=False)
    starts: np.ndarray = field(repr=False)
    term_pixel: np.ndarray = field(repr=False)
    term_value: np.ndarray = field(repr=False)
    term_slot: np.ndarray = field(repr=False)
    term_alpha: np.ndarray = field(repr=False)
    counts: np.ndarray = field(repr=False)

    @classmethod
    def build(
        cls,
        plane: Plane,
        shape: Any,
        spacing: Any,
        brick: Any,
        packing: PackingInfo,
        sampling: str,
        weight_bits: int | None = None,
    ) -> PlanePlan:
        """The plan of ``plane`` on a packed store (refusals: :func:`plane_kind`, the size limits)."""
        if not isinstance(plane, Plane):
            raise ParameterError(f"plane: expected a hevr.Plane, got {type(plane).__name__}")
        sampling = check_choice("sampling", sampling, ("nearest", "trilinear"))
        wb = packing.weight_bits if weight_bits is None else check_int("weight_bits", weight_bits, 0, MAX_WEIGHT_BITS)
        shape = tuple(int(s) for s in shape)
        sp = np.asarray(check_spacing(spacing), dtype=np.float64)
        kind = plane_kind(plane, packing.axis)
        check_render_size(plane, shape, tuple(sp), plane.slab_step)
        pix, pos = _samples(plane, shape, sp)
        a = packing.axis
        b_ax, c_ax = [ax for ax in range(3) if ax != a]
        ids, ws, n_corner = _footprints(pos[:, 2 - b_ax], pos[:, 2 - c_ax], shape[b_ax], shape[c_ax], sampling, wb)
        layers, alphas = _layers(pos[:, 2 - a], shape[a], sampling)
        # footprints: the distinct (voxels, weights) rows
        rows = np.concatenate([ids, ws], axis=1) if len(ids) else np.zeros((0, 2 * n_corner), np.int64)
        uniq, fp_of = np.unique(rows, axis=0, return_inverse=True)
        fp_of = fp_of.reshape(-1)
        F = len(uniq)
        keep = uniq[:, n_corner:] > 0
        fp_id = np.broadcast_to(np.arange(F)[:, None], keep.shape)[keep].astype(np.int64)
        flat = uniq[:, :n_corner][keep]
        fp_b, fp_c = np.divmod(flat, shape[c_ax])
        fp_w = uniq[:, n_corner:][keep].astype(np.int64)
        # the terms: per sample its (one or two) layers
        t_pix = np.repeat(pix, layers.shape[1])
        t_fp = np.repeat(fp_of, layers.shape[1])
        t_layer, t_alpha = layers.reshape(-1), alphas.reshape(-1)
        used = t_alpha > 0
        t_pix, t_fp, t_layer, t_alpha = t_pix[used], t_fp[used], t_layer[used], t_alpha[used]
        S = packing.slots
        packs = np.zeros((F, 2), np.int64)
        if F:
            lo = np.full(F, np.iinfo(np.int64).max)
            hi = np.full(F, -1)
            np.minimum.at(lo, t_fp, t_layer // S)
            np.maximum.at(hi, t_fp, t_layer // S)
            packs[:, 0], packs[:, 1] = lo, hi + 1
        starts = np.r_[0, np.cumsum(packs[:, 1] - packs[:, 0])].astype(np.int64)
        t_value = starts[t_fp] + t_layer // S - packs[t_fp, 0]
        counts = np.bincount(pix, minlength=plane.width * plane.height).astype(np.int64)
        return cls(
            plane,
            packing,
            shape,
            _triple(brick),
            sampling,
            wb,
            kind,
            fp_id,
            fp_b.astype(np.int64),
            fp_c.astype(np.int64),
            fp_w,
            packs,
            starts,
            t_pix,
            t_value,
            (t_layer % S).astype(np.int64),
            t_alpha,
            counts,
        )

    # -- sizes ------------------------------------------------------------------------------
    @property
    def n_footprints(self) -> int:
        return len(self.packs)

    @property
    def n_values(self) -> int:
        """The output ciphertexts (one per footprint and pack)."""
        return int(self.starts[-1])

    @property
    def unit(self) -> int:
        """The weight of one whole sample: U = 2^weight_bits (trilinear) or 1 (nearest)."""
        return 1 << self.weight_bits if self.sampling == "trilinear" else 1

    @property
    def n_tiles(self) -> int:
        return -(-self.n_values // TILE_VALUES)

    classes = 1  # no combine: every output value is one accumulator (its verification's one class)

    def value_ids(self, t: int) -> np.ndarray:
        """The ids of merge tile ``t``'s output values, in order (their verification coefficients)."""
        return np.arange(*self.tile_bounds(t))

    def key_values(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per product key its output value and class 0 (a slice's values are not combined)."""
        return keys, np.zeros_like(keys)

    def tile_bounds(self, t: int) -> tuple[int, int]:
        """The output values ``[v0, v1)`` of merge tile ``t``."""
        return int(t) * TILE_VALUES, min((int(t) + 1) * TILE_VALUES, self.n_values)

    @property
    def hits(self) -> np.ndarray:
        """(H, W) bool: the pixels with a sample inside the volume."""
        return (self.counts > 0).reshape(self.plane.height, self.plane.width)

    def weight_totals(self) -> np.ndarray:
        """W_F = Σ_f w_f of every footprint, (F,) int64."""
        return np.bincount(self.fp_id, weights=self.fp_w, minlength=self.n_footprints).astype(np.int64)

    def value_layers(self) -> tuple[np.ndarray, np.ndarray]:
        """Per output value its footprint and its first layer S·A, (V,) int64 each."""
        fp = np.repeat(np.arange(self.n_footprints), self.packs[:, 1] - self.packs[:, 0])
        A = np.arange(self.n_values) - self.starts[fp] + self.packs[fp, 0]
        return fp, A * self.packing.slots

    # -- the map's pairs -------------------------------------------------------------------
    def brick_pairs(self, index: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(output value, local pack, weight) of every product of brick ``index``, sorted by value
        (stable); the local pack indexes the brick's packed chunk in C order."""
        a, S = self.packing.axis, self.packing.slots
        b_ax, c_ax = [ax for ax in range(3) if ax != a]
        box = [(int(i) * b, min((int(i) + 1) * b, s)) for i, b, s in zip(index, self.brick, self.shape)]
        (b0, b1), (c0, c1), (a0, a1) = box[b_ax], box[c_ax], box[a]
        A0, A1 = a0 // S, -(-a1 // S)
        if not self.n_footprints or A1 <= int(self.packs[:, 0].min()) or A0 >= int(self.packs[:, 1].max()):
            empty = np.zeros(0, np.int64)  # no pack of this brick is computed (an axial slice's other layers)
            return empty, empty, empty
        sel = (self.fp_b >= b0) & (self.fp_b < b1) & (self.fp_c >= c0) & (self.fp_c < c1)
        fp, fb, fc, fw = self.fp_id[sel], self.fp_b[sel], self.fp_c[sel], self.fp_w[sel]
        lo, hi = np.maximum(self.packs[fp, 0], A0), np.minimum(self.packs[fp, 1], A1)
        n = np.maximum(hi - lo, 0)
        rep = np.repeat(np.arange(len(fp)), n)
        A = lo[rep] + np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        values = self.starts[fp[rep]] + A - self.packs[fp[rep], 0]
        dims = [0, 0, 0]
        dims[b_ax], dims[c_ax], dims[a] = b1 - b0, c1 - c0, A1 - A0
        loc = [np.empty(0, np.int64)] * 3  # per axis of the brick, each set below
        loc[b_ax], loc[c_ax], loc[a] = fb[rep] - b0, fc[rep] - c0, A - A0
        flat = (loc[0] * dims[1] + loc[1]) * dims[2] + loc[2]
        order = np.argsort(values, kind="stable")
        return values[order].astype(np.int64), flat[order].astype(np.int64), fw[rep][order]

    def brick_tiles(self, index: Any) -> list[int]:
        """The merge tiles brick ``index``'s products reach (sorted)."""
        values = self.brick_pairs(index)[0]
        return sorted({int(t) for t in np.unique(values // TILE_VALUES)})

    # -- the plaintext twin (tests: the slot values without encryption) ---------------------
    def plain_values(self, slot_values: np.ndarray) -> np.ndarray:
        """(V, S) int64: the slots every output value must decrypt to, from the unpacked slot values
        ``u`` (the volume's mantissas less the offset; layers past the end count 0)."""
        u = np.asarray(slot_values, dtype=np.int64)
        S, a = self.packing.slots, self.packing.axis
        b_ax, c_ax = [ax for ax in range(3) if ax != a]
        u = np.moveaxis(u, (a, b_ax, c_ax), (0, 1, 2))
        fp, first = self.value_layers()
        out = np.zeros((self.n_values, S), np.int64)
        for e in range(len(self.fp_id)):
            vals = np.flatnonzero(fp == self.fp_id[e])
            for s in range(S):
                L = first[vals] + s
                ok = L < u.shape[0]
                out[vals[ok], s] += self.fp_w[e] * u[L[ok], self.fp_b[e], self.fp_c[e]]
        return out


def _samples(plane: Plane, shape: tuple, sp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every inside slab sample: its pixel (N,) and index-space point (N, 3) in world order
    (x/sx, y/sy, z/sz), computed as :func:`hevr.render_slice_plain` computes them."""
    nz, ny, nx = shape
    upper = np.array([nx - 1, ny - 1, nz - 1], dtype=np.int64)
    box = upper * sp
    tol = 1e-9 * np.maximum(box, sp)
    u, v = np.asarray(plane.u, dtype=np.float64), np.asarray(plane.v, dtype=np.float64)
    normal = np.cross(u, v)
    normal /= np.linalg.norm(normal)
    du, dv = plane.pixel_spacing
    pix = np.arange(plane.width * plane.height, dtype=np.int64)
    rows, cols = np.divmod(pix, plane.width)
    centre = np.asarray(plane.origin) + (cols * du)[:, None] * u + (rows * dv)[:, None] * v
    pixs, points = [], []
    for k in range(plane.slab):
        world = centre + ((k - (plane.slab - 1) / 2.0) * plane.slab_step) * normal
        inside = np.all((world >= -tol) & (world <= box + tol), axis=1)
        pixs.append(pix[inside])
        points.append(world[inside] / sp)
    return np.concatenate(pixs), np.concatenate(points).reshape(-1, 3)


def _footprints(
    pb: np.ndarray, pc: np.ndarray, nb: int, nc: int, sampling: str, wb: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Per sample its in-slice voxels (flat b·nc + c, ascending, −1 unused) and integer weights
    (0 unused): (N, C) each, C = 1 (nearest) or 4, duplicates (clamped at a face) merged."""
    if sampling == "nearest":
        b = np.clip(np.floor(pb + 0.5).astype(np.int64), 0, nb - 1)
        c = np.clip(np.floor(pc + 0.5).astype(np.int64), 0, nc - 1)
        return (b * nc + c)[:, None], np.ones((len(pb), 1), np.int64), 1
    U = float(1 << wb)
    b0, c0 = np.floor(pb), np.floor(pc)
    fb, fc = pb - b0, pc - c0
    ids, ws = [], []
    for db, phib in ((0, 1.0 - fb), (1, fb)):
        for dc, phic in ((0, 1.0 - fc), (1, fc)):
            b = np.clip(b0.astype(np.int64) + db, 0, nb - 1)
            c = np.clip(c0.astype(np.int64) + dc, 0, nc - 1)
            ids.append(b * nc + c)
            ws.append(np.floor(phib * phic * U + 0.5).astype(np.int64))
    ids_a, ws_a = np.stack(ids, axis=1), np.stack(ws, axis=1)
    order = np.argsort(ids_a, axis=1, kind="stable")
    ids_a, ws_a = np.take_along_axis(ids_a, order, 1), np.take_along_axis(ws_a, order, 1)
    for j in range(1, 4):  # equal voxels are adjacent once sorted: carry the weight forward
        dup = ids_a[:, j] == ids_a[:, j - 1]
        ws_a[dup, j] += ws_a[dup, j - 1]
        ws_a[dup, j - 1] = 0
    ids_a = np.where(ws_a > 0, ids_a, -1)
    order = np.argsort(ids_a, axis=1, kind="stable")  # canonical: unused first
    return np.take_along_axis(ids_a, order, 1), np.take_along_axis(np.where(ws_a > 0, ws_a, 0), order, 1), 4


def _layers(pa: np.ndarray, na: int, sampling: str) -> tuple[np.ndarray, np.ndarray]:
    """Per sample the layers along ``a`` and their float64 factors α, (N, 1) or (N, 2), clamped
    to the volume as the reference clamps them."""
    if sampling == "nearest":
        return np.clip(np.floor(pa + 0.5).astype(np.int64), 0, na - 1)[:, None], np.ones((len(pa), 1))
    base = np.floor(pa)
    f = pa - base
    b = base.astype(np.int64)
    layers = np.stack([np.clip(b, 0, na - 1), np.clip(b + 1, 0, na - 1)], axis=1)
    return layers, np.stack([1.0 - f, f], axis=1)


def packed_slice_error_bound(meta: Any, plane: Plane, sampling: str, weight_bits: int | None = None) -> np.ndarray:
    """Per-pixel bound (H, W) on |decrypted packed slice − :func:`hevr.render_slice_plain`| (module
    docstring): 2V/U per sample for the rounded in-slice weights (trilinear), plus a float store's
    rounding 0.5·10^e·(1 + 2/U); a mean of samples keeps the bound; 0 where no sample is inside."""
    plan = PlanePlan.build(plane, meta.shape, meta.spacing, meta.brick, meta.packing, sampling, weight_bits)
    lo, hi = (float(v) for v in meta.value_range)
    D = max(abs(lo), abs(hi))
    U = float(plan.unit)
    weights = 2.0 * D / U if sampling == "trilinear" else 0.0
    store = 0.5 * 10.0**meta.scalar.exponent * (1 + 2 / U) if meta.scalar.digits is not None else 0.0
    per = (weights + store) * 1.0001 + 1e-9 * max(D, 1.0)  # float64 rounding of the finishing
    return np.where(plan.hits, per, 0.0)


def _triple(brick: Any) -> tuple[int, int, int]:
    """A brick shape as three Python ints."""
    bz, by, bx = (int(b) for b in brick)
    return bz, by, bx
