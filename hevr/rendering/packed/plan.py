"""The frame plan of a packed store: which packed ciphertexts each accumulator multiplies, with
which public weights, and how the key holder decodes the result (:class:`SlicePlan`).

A packed store (:mod:`hevr.store.packing`) holds, per column A along the packing axis ``a``,
Enc(P[A]) with slot s of P[A] the voxel S·A + s. A view's shear-warp geometry
(:mod:`hevr.rendering.packed.shear`) has ray (i, j) read, on slice k, the voxel i + m along ``a``
(m = m_k for nearest; m_k and m_k + 1 for bilinear) and the voxel y (or y, y + 1) of row j along
``b``, with public weight w (the bilinear factors' product, rounded: it depends on k, on which
neighbour, and on the row, never on i). Write
m − m_lo = S·q + o (o ∈ [0, S), m_lo the smallest m of the frame). Pack A then serves, in its slot
s, ray i = S·(A − q) + s − o − m_lo: so the product Enc(P[A])^w goes into the accumulator

    acc[B = A − q, j, o]       (slot s of it: ray S·B + s − o − m_lo),

and one product serves S rays. The classes o in use are 0 … O, O = min(S − 1, m_hi − m_lo)
(labelling them from m_lo, not from 0, shrinks the combine when the view's shift along ``a`` spans
fewer than S voxels — an orbit around the packing axis needs one class). Each (B, j) is then
combined by Horner,

    T[B, j] = Π_o acc[B, j, o]^(2^(K·(O − o)))          (K·O squarings and O products),

after which slot t of T[B, j] (t ∈ [0, S + O)) holds ray S·B + t − O − m_lo for every class. The
key holder decrypts one number per (B, j), checks that the bits above slot S + O − 1 are zero (the
integrity margin) and that every slot is at most the largest sum its ray can have, and adds the
slots of the blocks that share a ray. Every slot sum is below span·W_r ≤ span·(U + 2)·N_p < 2^K
(:meth:`SlicePlan.check_slots`), so the sums are exact integers; the weights are the bilinear
factors' products rounded to multiples of 1/U, U = 2^weight_bits (nearest: 1).

Work per frame: map ≈ (pairs)/S products of small exponents (nearest: one multiplication per
pack and slice), merge one product per extra brick partial, combine K·O squarings per S rays,
and one decryption per S rays.

>>> from hevr.rendering.geometry.camera import Camera
>>> from hevr.store.packing import PackingInfo
>>> cam = Camera.orbit((8, 8, 8), azimuth=90, width=4, height=4, parallel=True)
>>> plan = SlicePlan.build(cam, (8, 8, 8), (1.0, 1.0, 1.0), (4, 8, 8),
...                        PackingInfo(axis=0, slots=4, slot_bits=24, weight_bits=8, offset=0), "nearest")
>>> plan.classes, plan.m_lo        # an orbit around the packing axis: one class, no combine
(1, 0)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.validate import check_choice, check_int
from ...errors import RenderPlanError
from ...store.packing import MAX_WEIGHT_BITS, PackingInfo, mantissa_range
from .shear import ShearGeometry, check_plan_size

__all__ = ["SlicePlan"]


@dataclass(frozen=True, eq=False)
class SlicePlan:
    """One frame of a packed store, planned from public parameters only (module docstring).

    Attributes
    ----------
    geometry : ShearGeometry
    packing : PackingInfo
    sampling : {"nearest", "trilinear"}
        ``trilinear`` is bilinear within the slice.
    weight_bits : int
        Bits of the bilinear weights (U = 2^weight_bits; nearest weights are 1).
    brick : (int, int, int)
        The store's voxel brick.
    tile : int
        Rows ``j`` per reduce tile (and ``max(1, tile // S)`` blocks).
    a_steps : (N_p, 2) int64, a_frac : (N_p,) float64
        Per slice, the voxel offsets m (nearest: m_k and a disabled second, −2^40) and the
        bilinear fraction f_a along ``a`` (the ``b`` side per slice and row: :meth:`b_table`).
    m_lo, classes : int
        The class labelling: m_lo, and O + 1.
    block_range : (int, int)
        The blocks B computed, ``[lo, hi)``.
    """

    geometry: ShearGeometry
    packing: PackingInfo
    sampling: str
    weight_bits: int
    brick: tuple[int, int, int]
    tile: int
    a_steps: np.ndarray = field(repr=False)
    a_frac: np.ndarray = field(repr=False)
    m_lo: int
    classes: int
    block_range: tuple[int, int]

    @classmethod
    def build(
        cls,
        camera: Any,
        shape: Any,
        spacing: Any,
        brick: Any,
        packing: PackingInfo,
        sampling: str,
        tile: int = 32,
        weight_bits: int | None = None,
    ) -> SlicePlan:
        """The plan of ``camera`` on a packed store (refusals: :meth:`ShearGeometry.of`)."""
        sampling = check_choice("sampling", sampling, ("nearest", "trilinear"))
        tile = check_int("tile", tile, 1, 4096)
        wb = packing.weight_bits if weight_bits is None else check_int("weight_bits", weight_bits, 0, MAX_WEIGHT_BITS)
        geo = ShearGeometry.of(camera, shape, spacing, axis=packing.axis)
        check_plan_size(geo)  # before any array per slice and row: metadata may come from anyone
        a_steps, a_frac = _a_side(geo, sampling, wb)
        S = packing.slots
        used = a_steps[a_steps > _OFF]
        m_lo, m_hi = (int(used.min()), int(used.max())) if used.size else (0, 0)
        o_max = min(S - 1, m_hi - m_lo)
        i_lo, i_hi = geo.i_range
        blocks = (0, 0) if i_hi <= i_lo else ((i_lo + m_lo) // S, (i_hi - 1 + o_max + m_lo) // S + 1)
        bz, by, bx = (int(b) for b in brick)
        return cls(geo, packing, sampling, wb, (bz, by, bx), tile, a_steps, a_frac, m_lo, o_max + 1, blocks)

    @classmethod
    def of_store(
        cls, meta: Any, camera: Any, sampling: str, tile: int = 32, weight_bits: int | None = None
    ) -> SlicePlan:
        """The frame plan of ``camera`` on the packed store of metadata ``meta``, its slots checked
        (:meth:`check_slots`): the one plan the in-process render, ``hevr serve`` and the remote key
        holder each build from the same public request."""
        plan = cls.build(camera, meta.shape, meta.spacing, meta.brick, meta.packing, sampling, tile, weight_bits)
        lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
        plan.check_slots(hi - lo)  # before any work: no sum may carry into the next slot
        return plan

    def __getstate__(self) -> dict:  # the b side is recomputed where it is used, not pickled
        return {k: v for k, v in self.__dict__.items() if k != "_b"}

    def b_table(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``b`` side: per slice and row, the voxel y of neighbour 0 (N_p, N_j) int64, and the
        weights' ``b`` factors (N_p, N_j, 2) float64 (nearest: 1 and 0)."""
        if "_b" not in self.__dict__:
            g = self.geometry
            _, cb = g.offsets()
            y = g.row_positions()[None, :] + cb[:, None]
            if self.sampling == "nearest":
                yb = np.floor(y + 0.5)
                phi = np.stack([np.ones_like(y), np.zeros_like(y)], axis=-1)
            else:
                yb = np.floor(y)
                f = y - yb
                phi = np.stack([1.0 - f, f], axis=-1)
            object.__setattr__(self, "_b", (yb.astype(np.int64), phi))
        return self.__dict__["_b"]

    def a_table(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``a`` side: per slice, the offsets m of neighbours 0 and 1 (N_p, 2) int64 (a
        neighbour not used: a huge negative offset) and their factors (N_p, 2) float64."""
        f = self.a_frac
        phi = (
            np.stack([1.0 - f, f], axis=-1)
            if self.sampling == "trilinear"
            else np.stack([np.ones_like(f), np.zeros_like(f)], axis=-1)
        )
        return self.a_steps, phi

    def weights(self, phi_a: np.ndarray, phi_b: np.ndarray) -> np.ndarray:
        """The integer weights of factors ``phi_a`` × ``phi_b`` (broadcast): round(φ_a·φ_b·U), or 1
        for nearest's (1 × 1) and 0 for any zero factor."""
        if self.sampling == "nearest":
            return ((phi_a > 0) & (phi_b > 0)).astype(np.int64)
        return np.floor(phi_a * phi_b * float(1 << self.weight_bits) + 0.5).astype(np.int64)

    # -- sizes ------------------------------------------------------------------------------
    @property
    def slots_out(self) -> int:
        """Slots per combined value, S + O."""
        return self.packing.slots + self.classes - 1

    @property
    def unit(self) -> int:
        """The weight of one whole sample: U = 2^weight_bits (bilinear) or 1 (nearest)."""
        return 1 << self.weight_bits if self.sampling == "trilinear" else 1

    @property
    def n_blocks(self) -> int:
        return self.block_range[1] - self.block_range[0]

    @property
    def tile_blocks(self) -> int:
        return max(1, self.tile // self.packing.slots)

    @property
    def tiles_shape(self) -> tuple[int, int]:
        """(tiles along j, tiles along B)."""
        nj = self.geometry.size[1]
        return -(-nj // self.tile), -(-self.n_blocks // self.tile_blocks)

    @property
    def n_tiles(self) -> int:
        ty, tx = self.tiles_shape
        return ty * tx

    @property
    def n_values(self) -> int:
        """The frame's combined values (rows × blocks): one component's verification coefficients."""
        return self.geometry.size[1] * self.n_blocks

    def value_ids(self, t: int) -> np.ndarray:
        """The global ids of tile ``t``'s combined values, in the tile's order ((j, B) row-major):
        j·N_B + (B − B_lo), the indices of their verification coefficients."""
        j0, j1, b0, b1 = self.tile_bounds(t)
        return (np.arange(j0, j1)[:, None] * self.n_blocks + np.arange(b0, b1)[None, :]).reshape(-1)

    def key_values(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per accumulator key its combined value's global id and its slot class (the Horner shift)."""
        return keys // self.classes, keys % self.classes

    def tile_bounds(self, t: int) -> tuple[int, int, int, int]:
        """(j0, j1, B0, B1), offsets from the image's first row and block, of tile ``t``."""
        ty, tx = self.tiles_shape
        r, c = divmod(int(t), tx)
        nj = self.geometry.size[1]
        return (
            r * self.tile,
            min((r + 1) * self.tile, nj),
            c * self.tile_blocks,
            min((c + 1) * self.tile_blocks, self.n_blocks),
        )

    # -- slot safety -------------------------------------------------------------------------
    def weight_totals(self, i_range: tuple[int, int] | None = None) -> np.ndarray:
        """W(i, j) = Σ of the weights of ray (i, j) on voxels inside the volume: (N_i, N_j) int64
        (``i_range``: of these rays along ``a`` instead of the frame's)."""
        ina, inb, w = self._masks(i_range)
        out = np.zeros((ina.shape[-1], inb.shape[1]), np.int64)
        for da in range(2):
            G = (w[:, da] * inb).sum(axis=-1)  # (N_p, N_j): Σ over the b neighbours
            out += ina[:, da].astype(np.int64).T @ G
        return out

    def check_slots(self, span: int) -> np.ndarray:
        """Refuse (:class:`hevr.RenderPlanError`, naming ``weight_bits``) a frame whose largest ray
        sum, span·max W, could reach 2^K and carry into the next slot; returns W."""
        W = self.weight_totals()
        top = int(span) * int(W.max()) if W.size else 0
        K = self.packing.slot_bits
        if top >> K:
            raise RenderPlanError(
                f"weight_bits: expected in-slice weights whose largest ray sum fits a {K}-bit slot of this packed "
                f"store, got weight_bits={self.weight_bits}: the largest sum {span}·{int(W.max())} needs "
                f"{top.bit_length()} bits; use weight_bits={self.packing.weight_bits} (the store's) or fewer"
            )
        return W

    # -- the map's pairs -------------------------------------------------------------------
    def _masks(self, i_range: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whether the voxels exist: along ``a`` (N_p, 2, N_i), along ``b`` (N_p, N_j, 2); and the
        weights (N_p, 2, N_j, 2)."""
        g = self.geometry
        m, pa = self.a_table()
        yb, pb = self.b_table()
        i = np.arange(*(g.i_range if i_range is None else i_range), dtype=np.int64)
        xa = i[None, None, :] + m[:, :, None]
        ina = (xa >= 0) & (xa < g.shape[g.axis])
        y = yb[:, :, None] + np.arange(2)[None, None, :]
        inb = (y >= 0) & (y < g.shape[g.other])
        w = self.weights(pa[:, :, None, None], pb[:, None, :, :])
        return ina, inb, w

    def _brick_box(self, index: Any) -> tuple[tuple[int, int], ...]:
        g = self.geometry
        return tuple((int(i) * b, min((int(i) + 1) * b, s)) for i, b, s in zip(index, self.brick, g.shape))

    def brick_pairs(self, index: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keys, local pack, weight) of every product of brick ``index``, sorted by key (stable).

        A key numbers the accumulator (B, r, o) (r: the row) as (r·N_B + (B − B_lo))·(O + 1) + (O − o),
        so that a (B, r)'s classes are consecutive with the class to shift most last (the order
        the backend's Horner ``pack`` takes); the local pack indexes the brick's packed chunk in C order."""
        g, S = self.geometry, self.packing.slots
        box = self._brick_box(index)
        (k0, k1), (a0, a1), (y0, y1) = box[g.principal], box[g.axis], box[g.other]
        empty = np.zeros(0, np.int64)
        if self.n_blocks == 0 or g.size[1] == 0:
            return empty, empty, empty
        m_all, pa = self.a_table()
        yb_all, pb = self.b_table()
        A = np.arange(a0 // S, -(-a1 // S), dtype=np.int64)
        dims = [0, 0, 0]
        dims[g.principal], dims[g.axis], dims[g.other] = k1 - k0, len(A), y1 - y0
        o_max, NB = self.classes - 1, self.n_blocks
        keys, local, wts = [], [], []
        for da in range(2):
            for db in range(2):
                y = yb_all[k0:k1] + db
                w = self.weights(pa[k0:k1, da][:, None], pb[k0:k1, :, db])
                kk, rr = np.nonzero((y >= y0) & (y < y1) & (w > 0) & (m_all[k0:k1, da] > _OFF)[:, None])
                if not len(kk):
                    continue
                q, o = np.divmod(m_all[k0 + kk, da] - self.m_lo, S)
                B = A[None, :] - q[:, None]
                keep = (B >= self.block_range[0]) & (B < self.block_range[1])
                key = (rr[:, None] * NB + (B - self.block_range[0])) * self.classes + (o_max - o)[:, None]
                loc = [np.empty(0, np.int64)] * 3  # per axis of the brick, each set below
                loc[g.principal] = kk[:, None]
                loc[g.axis] = (A - a0 // S)[None, :]
                loc[g.other] = (y[kk, rr] - y0)[:, None]
                flat = (loc[0] * dims[1] + loc[1]) * dims[2] + loc[2]
                keys.append(key[keep])
                local.append(np.broadcast_to(flat, key.shape)[keep])
                wts.append(np.broadcast_to(w[kk, rr][:, None], key.shape)[keep])
        if not keys:
            return empty, empty, empty
        keys_a, local_a, w_a = np.concatenate(keys), np.concatenate(local), np.concatenate(wts)
        order = np.argsort(keys_a, kind="stable")
        return keys_a[order], local_a[order], w_a[order]

    def block_rays(self) -> tuple[int, int]:
        """The rays along ``a`` whose sums the combined values hold, ``[lo, hi)``: slot t of block B
        is ray S·B + t − O − m_lo (the frame's rays and the blocks' other slots)."""
        S, o_max = self.packing.slots, self.classes - 1
        return S * self.block_range[0] - o_max - self.m_lo, S * (self.block_range[1] - 1) + S - self.m_lo

    def tile_of(self, keys: np.ndarray) -> np.ndarray:
        """The reduce tile of every accumulator key."""
        acc = keys // self.classes
        jr, br = acc // self.n_blocks, acc % self.n_blocks
        return (jr // self.tile) * self.tiles_shape[1] + br // self.tile_blocks

    def brick_tiles(self, index: Any) -> list[int]:
        """The tiles brick ``index``'s products can reach (from the ranges of its slices' offsets
        and the rows that read its voxels; a superset: a tile may get no product)."""
        g, S = self.geometry, self.packing.slots
        box = self._brick_box(index)
        (k0, k1), (a0, a1), (y0, y1) = box[g.principal], box[g.axis], box[g.other]
        if self.n_blocks == 0 or g.size[1] == 0:
            return []
        m = self.a_table()[0][k0:k1]
        m = m[m > _OFF]
        yb = self.b_table()[0][k0:k1]
        rows = np.nonzero(((yb + 1 >= y0) & (yb < y1)).any(axis=0))[0]
        if not m.size or not rows.size:
            return []
        q = (m - self.m_lo) // S
        B0 = max(a0 // S - int(q.max()), self.block_range[0])
        B1 = min(-(-a1 // S) - 1 - int(q.min()), self.block_range[1] - 1)
        if B1 < B0:
            return []
        tb0, tb1 = (B0 - self.block_range[0]) // self.tile_blocks, (B1 - self.block_range[0]) // self.tile_blocks
        ty0, ty1 = int(rows[0]) // self.tile, int(rows[-1]) // self.tile
        tx = self.tiles_shape[1]
        return [r * tx + c for r in range(ty0, ty1 + 1) for c in range(tb0, tb1 + 1)]

    # -- the plaintext twin (tests: the same sums without packing) -------------------------
    def plain_sums(self, slot_values: np.ndarray) -> np.ndarray:
        """Σ w·u of every intermediate ray from the unpacked slot values ``u`` (the volume's
        mantissas less the offset), int64 — the integers a frame must decrypt to, exactly."""
        g = self.geometry
        u = np.moveaxis(np.asarray(slot_values, dtype=np.int64), (g.principal, g.axis, g.other), (0, 1, 2))
        m, pa = self.a_table()
        yb, pb = self.b_table()
        i = np.arange(*g.i_range)
        out = np.zeros(g.size, np.int64)
        for k in range(g.slices):
            for da in range(2):
                if m[k, da] <= _OFF:
                    continue
                xa = i + m[k, da]
                oka = (xa >= 0) & (xa < u.shape[1])
                for db in range(2):
                    y = yb[k] + db
                    w = self.weights(pa[k, da], pb[k, :, db])
                    okb = (y >= 0) & (y < u.shape[2]) & (w > 0)
                    out[np.ix_(oka, okb)] += w[okb][None, :] * u[k][np.ix_(xa[oka], y[okb])]
        return out

    # -- the bound against the float64 reference ------------------------------------------
    def contributing_slices(self) -> np.ndarray:
        """Per ray, the slices whose sample has a non-zero factor on some voxel inside: (N_i, N_j)
        (an upper bound of the slices where the frame's or the reference's sample is not zero)."""
        ina, inb, _ = self._masks()
        m, pa = self.a_table()
        _, pb = self.b_table()
        anya = (ina & ((pa > 0) & (m > _OFF))[:, :, None]).any(axis=1)
        anyb = (inb & (pb > 0)).any(axis=-1)
        return np.asarray(anya, np.int64).T @ np.asarray(anyb, np.int64)


_OFF = -(1 << 40)  # the offset of a neighbour not used


def _a_side(geo: ShearGeometry, sampling: str, weight_bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Per slice the ``a`` offsets of neighbours 0 and 1 and the fraction f_a: nearest m_k =
    floor(c_a + 0.5) alone; bilinear floor(c_a) and floor(c_a) + 1, each only where its factor
    (1 − f_a or f_a) can give a non-zero rounded weight (≥ 1/2U)."""
    ca, _ = geo.offsets()
    if sampling == "nearest":
        m = np.floor(ca + 0.5).astype(np.int64)
        return np.stack([m, np.full_like(m, _OFF)], axis=1), np.zeros_like(ca)
    m0 = np.floor(ca)
    f = ca - m0
    U = float(1 << weight_bits)
    m0 = m0.astype(np.int64)
    steps = np.stack(
        [np.where(np.floor((1.0 - f) * U + 0.5) > 0, m0, _OFF), np.where(np.floor(f * U + 0.5) > 0, m0 + 1, _OFF)],
        axis=1,
    )
    return steps, f
