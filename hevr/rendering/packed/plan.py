"""The frame plan of a packed store: which packed ciphertexts each accumulator multiplies, with
which public weights, and how the key holder decodes the result (:class:`SlicePlan`).

A packed store (:mod:`hevr.store.packing`) holds, per column A along the packing axis ``a``,
Enc(P[A]) with slot s of P[A] the voxel S·A + s. A view's shear-warp geometry
(:mod:`hevr.rendering.packed.shear`) has ray (i, j) read, on slice k, the voxel i + m along ``a``
(m = m_k for nearest; m_k and m_k + 1 for bilinear) with public weight w. Write
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

from ..._validate import check_choice, check_int
from ...errors import IntegrityError, RenderPlanError
from ...store.packing import INTEGRITY_BITS, MAX_WEIGHT_BITS, PackingInfo, unpack_slots
from .shear import ShearGeometry

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
    terms : (T, 4) int64
        One (k, m_a, m_b, w) per slice and in-slice neighbour with a non-zero weight, sorted by k.
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
    terms: np.ndarray = field(repr=False)
    m_lo: int
    classes: int
    block_range: tuple[int, int]

    @classmethod
    def build(cls, camera: Any, shape: Any, spacing: Any, brick: Any, packing: PackingInfo, sampling: str,
              tile: int = 32, weight_bits: int | None = None) -> "SlicePlan":
        """The plan of ``camera`` on a packed store (refusals: :meth:`ShearGeometry.of`)."""
        sampling = check_choice("sampling", sampling, ("nearest", "trilinear"))
        tile = check_int("tile", tile, 1, 4096)
        wb = packing.weight_bits if weight_bits is None else check_int("weight_bits", weight_bits, 0, MAX_WEIGHT_BITS)
        geo = ShearGeometry.of(camera, shape, spacing, axis=packing.axis)
        terms = _terms(geo, sampling, wb)
        S = packing.slots
        if len(terms):
            m_lo, m_hi = int(terms[:, 1].min()), int(terms[:, 1].max())
        else:
            m_lo = m_hi = 0
        O = min(S - 1, m_hi - m_lo)
        i_lo, i_hi = geo.i_range
        blocks = (0, 0) if i_hi <= i_lo else ((i_lo + m_lo) // S, (i_hi - 1 + O + m_lo) // S + 1)
        return cls(geo, packing, sampling, wb, tuple(int(b) for b in brick), tile, terms, m_lo, O + 1, blocks)

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

    def tile_bounds(self, t: int) -> tuple[int, int, int, int]:
        """(j0, j1, B0, B1), offsets from the image's first row and block, of tile ``t``."""
        ty, tx = self.tiles_shape
        r, c = divmod(int(t), tx)
        nj = self.geometry.size[1]
        return (r * self.tile, min((r + 1) * self.tile, nj), c * self.tile_blocks,
                min((c + 1) * self.tile_blocks, self.n_blocks))

    # -- slot safety -------------------------------------------------------------------------
    def weight_totals(self) -> np.ndarray:
        """W(i, j) = Σ of the weights of ray (i, j) on voxels inside the volume: (N_i, N_j) int64."""
        ina, inb = self._term_masks()
        w = self.terms[:, 3].astype(np.int64) if len(self.terms) else np.zeros(0, np.int64)
        return (ina.astype(np.int64) * w[:, None]).T @ inb.astype(np.int64)

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
                f"{top.bit_length()} bits; use weight_bits={self.packing.weight_bits} (the store's) or fewer")
        return W

    # -- the map's pairs -------------------------------------------------------------------
    def _term_masks(self) -> tuple[np.ndarray, np.ndarray]:
        """Per term, which rays' voxels exist along ``a`` (T, N_i) and along ``b`` (T, N_j)."""
        g = self.geometry
        t = self.terms
        i = np.arange(*g.i_range, dtype=np.int64)
        j = np.arange(*g.j_range, dtype=np.int64)
        xa = i[None, :] + t[:, 1:2]
        xb = j[None, :] + t[:, 2:3]
        return (xa >= 0) & (xa < g.shape[g.axis]), (xb >= 0) & (xb < g.shape[g.other])

    def _brick_box(self, index: Any) -> tuple[tuple[int, int], ...]:
        g = self.geometry
        return tuple((int(i) * b, min((int(i) + 1) * b, s)) for i, b, s in zip(index, self.brick, g.shape))

    def brick_pairs(self, index: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keys, local pack, weight) of every product of brick ``index``, sorted by key (stable).

        A key numbers the accumulator (B, j, o) as ((j − j_lo)·N_B + (B − B_lo))·(O + 1) + (O − o),
        so that a (B, j)'s classes are consecutive with the class to shift most last (the order
        the backend's Horner ``pack`` takes); the local pack indexes the brick's packed chunk in C order."""
        g, S = self.geometry, self.packing.slots
        box = self._brick_box(index)
        (k0, k1), (a0, a1), (y0, y1) = box[g.principal], box[g.axis], box[g.other]
        t = self.terms
        lo, hi = np.searchsorted(t[:, 0], [k0, k1])
        t = t[lo:hi]
        empty = np.zeros(0, np.int64)
        if not len(t) or self.n_blocks == 0:
            return empty, empty, empty
        A = np.arange(a0 // S, -(-a1 // S), dtype=np.int64)
        y = np.arange(y0, y1, dtype=np.int64)
        mrel = t[:, 1] - self.m_lo
        q, o = mrel // S, mrel % S
        B = A[None, :, None] - q[:, None, None] + np.zeros((1, 1, len(y)), np.int64)
        j = y[None, None, :] - t[:, 2][:, None, None] + np.zeros((1, len(A), 1), np.int64)
        O = self.classes - 1
        keep = (B >= self.block_range[0]) & (B < self.block_range[1]) & (j >= g.j_range[0]) & (j < g.j_range[1])
        keys = ((j - g.j_range[0]) * self.n_blocks + (B - self.block_range[0])) * self.classes + (O - o)[:, None, None]
        # the packed chunk's local coordinates, in array axis order
        loc = [None, None, None]
        loc[g.principal] = (t[:, 0] - k0)[:, None, None]
        loc[g.axis] = (A - a0 // S)[None, :, None]
        loc[g.other] = (y - y0)[None, None, :]
        dims = [k1 - k0, len(A), y1 - y0]
        cdims = [0, 0, 0]
        cdims[g.principal], cdims[g.axis], cdims[g.other] = dims
        local = (loc[0] * cdims[1] + loc[1]) * cdims[2] + loc[2]
        w = np.broadcast_to(t[:, 3][:, None, None], keys.shape)
        local = np.broadcast_to(local, keys.shape)
        keys, local, w = keys[keep], local[keep], w[keep]
        order = np.argsort(keys, kind="stable")
        return keys[order], local[order], w[order]

    def tile_of(self, keys: np.ndarray) -> np.ndarray:
        """The reduce tile of every accumulator key."""
        acc = keys // self.classes
        jr, br = acc // self.n_blocks, acc % self.n_blocks
        return (jr // self.tile) * self.tiles_shape[1] + br // self.tile_blocks

    def brick_tiles(self, index: Any) -> list[int]:
        """The tiles brick ``index``'s products can reach (from the ranges of its slices' terms;
        a superset: a tile may get no product)."""
        g, S = self.geometry, self.packing.slots
        box = self._brick_box(index)
        (k0, k1), (a0, a1), (y0, y1) = box[g.principal], box[g.axis], box[g.other]
        t = self.terms
        lo, hi = np.searchsorted(t[:, 0], [k0, k1])
        t = t[lo:hi]
        if not len(t) or self.n_blocks == 0:
            return []
        q = (t[:, 1] - self.m_lo) // S
        B0 = max(a0 // S - int(q.max()), self.block_range[0])
        B1 = min(-(-a1 // S) - 1 - int(q.min()), self.block_range[1] - 1)
        j0 = max(y0 - int(t[:, 2].max()), g.j_range[0])
        j1 = min(y1 - 1 - int(t[:, 2].min()), g.j_range[1] - 1)
        if B1 < B0 or j1 < j0:
            return []
        tb0, tb1 = (B0 - self.block_range[0]) // self.tile_blocks, (B1 - self.block_range[0]) // self.tile_blocks
        ty0, ty1 = (j0 - g.j_range[0]) // self.tile, (j1 - g.j_range[0]) // self.tile
        tx = self.tiles_shape[1]
        return [r * tx + c for r in range(ty0, ty1 + 1) for c in range(tb0, tb1 + 1)]

    # -- decoding (the key holder) ---------------------------------------------------------
    def decode(self, tiles: list[list[int]], span: int, W: np.ndarray) -> np.ndarray:
        """The exact ray sums Σ w·u (slot values, before the offset) of the intermediate image,
        (N_i, N_j) int64, from every tile's decrypted values (row-major (j, B) in the tile).

        Raises :class:`hevr.IntegrityError` for a value with a bit set above its last slot (the
        integrity margin: a corrupted ciphertext), a slot above its ray's largest sum, or a slot
        of a ray that reads no voxel holding anything."""
        g, S, K = self.geometry, self.packing.slots, self.packing.slot_bits
        O, n_out = self.classes - 1, self.slots_out
        ni, nj = g.size
        sums = np.zeros((ni, nj), np.int64)
        top = (np.asarray(W, dtype=object) * int(span)) if ni * nj else np.zeros((0, 0), object)
        limit = 1 << (n_out * K)
        if len(tiles) != self.n_tiles:
            raise IntegrityError(f"image: expected {self.n_tiles} tiles, got {len(tiles)}; the image was corrupted or "
                                 "tampered with; no image is returned")
        for t, vals in enumerate(tiles):
            j0, j1, b0, b1 = self.tile_bounds(t)
            if len(vals) != (j1 - j0) * (b1 - b0):
                raise IntegrityError(f"image: tile {t} holds {len(vals)} values, expected {(j1 - j0) * (b1 - b0)}; "
                                     "the image was corrupted or tampered with; no image is returned")
            for v in vals:
                if not 0 <= int(v) < limit:
                    raise IntegrityError(f"image: a value of tile {t} has bits set above its {n_out} slots of {K} "
                                         f"bits (the {INTEGRITY_BITS}-bit integrity margin): the image was corrupted "
                                         "or tampered with; no image is returned")
            slots = unpack_slots(vals, n_out, K).reshape(j1 - j0, b1 - b0, n_out)
            Bs = np.arange(b0, b1) + self.block_range[0]
            rays = S * Bs[:, None] + np.arange(n_out)[None, :] - O - self.m_lo - g.i_range[0]  # (blocks, slots)
            inside = (rays >= 0) & (rays < ni)
            for jj in range(j1 - j0):
                row = slots[jj]
                if (row[~inside] != 0).any():
                    raise IntegrityError(f"image: tile {t} has a non-zero slot for a ray outside the frame; the image "
                                         "was corrupted or tampered with; no image is returned")
                r = rays[inside]
                v = row[inside]
                jcol = j0 + jj
                bad = v.astype(object) > top[r, jcol]
                if bad.any():
                    raise IntegrityError(f"image: tile {t} has a slot above its ray's largest possible sum; the image "
                                         "was corrupted or tampered with; no image is returned")
                np.add.at(sums[:, jcol], r, v)
        return sums

    # -- the plaintext twin (tests: the same sums without packing) -------------------------
    def plain_sums(self, slot_values: np.ndarray) -> np.ndarray:
        """Σ w·u of every intermediate ray from the unpacked slot values ``u`` (the volume's
        mantissas less the offset), int64 — the integers a frame must decrypt to, exactly."""
        g = self.geometry
        u = np.moveaxis(np.asarray(slot_values, dtype=np.int64), (g.principal, g.axis, g.other), (0, 1, 2))
        i = np.arange(*g.i_range)
        j = np.arange(*g.j_range)
        out = np.zeros(g.size, np.int64)
        for k, ma, mb, w in self.terms.tolist():
            xa, xb = i + ma, j + mb
            oka, okb = (xa >= 0) & (xa < u.shape[1]), (xb >= 0) & (xb < u.shape[2])
            out[np.ix_(oka, okb)] += w * u[k][np.ix_(xa[oka], xb[okb])]
        return out

    # -- the bound against the float64 reference ------------------------------------------
    def contributing_slices(self) -> np.ndarray:
        """Per ray, the slices whose sample reads some voxel with a non-zero weight: (N_i, N_j)."""
        g = self.geometry
        ina, inb = self._term_masks()
        n = g.slices
        k = self.terms[:, 0]
        anya = np.zeros((n,) + ina.shape[1:], bool)
        anyb = np.zeros((n,) + inb.shape[1:], bool)
        np.logical_or.at(anya, k, ina)
        np.logical_or.at(anyb, k, inb)
        return anya.astype(np.int64).T @ anyb.astype(np.int64)


def _terms(geo: ShearGeometry, sampling: str, weight_bits: int) -> np.ndarray:
    """(k, m_a, m_b, w) of every slice's samples: one per slice (nearest, w = 1) or the 2×2 in-slice
    neighbours with w = round(φ_a·φ_b·U), φ ∈ {1 − f, f} the bilinear factors, U = 2^weight_bits
    (zero weights dropped; the four sum to U ± 2)."""
    ca, cb = geo.offsets()
    k = np.arange(geo.slices, dtype=np.int64)
    if sampling == "nearest":
        ma, mb = np.floor(ca + 0.5).astype(np.int64), np.floor(cb + 0.5).astype(np.int64)
        return np.stack([k, ma, mb, np.ones_like(k)], axis=1)
    U = float(1 << weight_bits)
    fa0, fb0 = np.floor(ca), np.floor(cb)
    fa, fb = ca - fa0, cb - fb0
    ma, mb = fa0.astype(np.int64), fb0.astype(np.int64)
    rows = []
    for da, pa in ((0, 1.0 - fa), (1, fa)):
        for db, pb in ((0, 1.0 - fb), (1, fb)):
            w = np.floor(pa * pb * U + 0.5).astype(np.int64)
            rows.append(np.stack([k, ma + da, mb + db, w], axis=1))
    t = np.concatenate(rows)
    t = t[t[:, 3] > 0]
    return t[np.lexsort((t[:, 2], t[:, 1], t[:, 0]))]
