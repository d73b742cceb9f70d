"""Server-side merging and pixel finishing: ⊕ of partial ray sums, per-pixel combination,
Eq. 1 normalisation, offset and packing — everything after the map step, in one place.

Every function here works on one image tile and only on public integers plus
ciphertexts; the secret key is never needed. The big-integer work goes through the
backend (:mod:`hevr.backends`): the records of a tile are converted once, combined, raised
and packed in the backend's form, and converted back once.

For a pixel whose ray hits the volume, with stored ray sums S_k (k = 1..K) and the
quantised combination matrix Q (K × C) of the render plan:

* combination: T_ch = Π_k S_k^Q[k,ch] (X-ray: T = S_1, no arithmetic);
* normalisation: the finished value is T^R with R = round(10^G/(n_samples·factor)), the
  rounded reciprocal of Eq. 1 (a plaintext exponent that depends on public data only);
* offset and packing: c = Π_j (T_j^R_j · g^O)^(B^j), B = 2^pack_bits, ``per_pack`` values
  each. Valid because every value M_j + O lies in [0, bound], bound < B, and
  per_pack·pack_bits <= bits(n) − 2: no digit carries and the plaintext stays below n/2.

Finishing units. A tile's packed ciphertexts are independent groups of ``per_pack`` values
in (pixel, channel) order, so a tile may be finished by several tasks, each over a run of
pixels whose first value starts a group: their outputs, concatenated, are the tile's
ciphertexts bit for bit. :func:`finish_units` cuts runs of about :data:`UNIT_MULS`
modular multiplications of a 2048-bit key (a value costs ``pack_bits`` squarings, about
``bits(R)/2`` multiplications for the reciprocal and its share of the combination), so that
no finishing task outlasts a typical map task and the finishing after the last map task is
spread over every worker instead of waiting on one tile.

Client finishing (:func:`~hevr.rendering.planning.planner.plan_sums`, the default): the plan has no
combination matrix and R = 1, so a tile's values are the K component sums S_k themselves,
offset and packed (b squarings and one product per value); the client divides and colours
(:mod:`hevr.colour`).

Pixels whose rays miss are skipped: which rays miss follows from the public camera and
volume shape, and the image records them in a public mask. A hit ray whose every weight
rounded to 0 has no partial sums: its sums are the trivial encryption 1 of 0.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...backends import Backend, get_backend
from ..planning.planner import RenderPlan

__all__ = ["finish_tile", "finish_units", "merge_partials", "one_records", "UNIT_MULS"]

UNIT_MULS = 1 << 13  # target work of one finishing task, in 2048-bit-key modular multiplications


def finish_units(plan: RenderPlan, hit: np.ndarray, key_bits: int) -> list[tuple[int, int]]:
    """Pixel runs ``[a, b)`` of one tile (``hit``: its pixels' hit mask, in tile order) to finish
    as separate tasks; each run but the first starts a new packing group.

    >>> from types import SimpleNamespace as NS
    >>> plan = NS(pack_bits=40, per_pack=2, channels_out=1, comb=None, recip_digits=6)
    >>> finish_units(plan, np.ones(1000, bool), 2048)[:2]
    [(0, 162), (162, 324)]
    >>> finish_units(plan, np.ones(1000, bool), 64)
    [(0, 1000)]
    """
    C = plan.channels_out
    K = C if plan.comb is None else len(plan.comb)
    per_value = max(1, plan.pack_bits) + 1.7 * plan.recip_digits + (0 if plan.comb is None else (2**K + 16 * K) / C)
    weight = max((key_bits / 2048) ** 1.6, 0.05)  # a mulmod's cost relative to a 2048-bit key's
    values = max(1, int(UNIT_MULS / (per_value * weight)))
    group = max(1, plan.per_pack)
    values = max(group, values // group * group)  # whole packing groups per unit
    n = len(hit)
    hits_before = np.concatenate([[0], np.cumsum(hit)]) * C  # values before each pixel
    starts = np.flatnonzero(hits_before[:n] % group == 0)  # pixels where a packing group may start
    units, a = [], 0
    while a < n:
        # the first group start at or after the pixel where the unit holds `values` values
        b = int(np.searchsorted(hits_before, hits_before[a] + values, side="left"))
        i = int(np.searchsorted(starts, max(b, a + 1)))
        b = int(starts[i]) if i < starts.size else n
        units.append((a, b))
        a = b
    return units


def one_records(shape: tuple[int, ...], width: int) -> np.ndarray:
    """Records of the integer 1 (the trivial encryption of 0), shape ``shape + (width,)``.

    >>> one_records((2,), 3).tolist()
    [[0, 0, 1], [0, 0, 1]]
    """
    out = np.zeros(tuple(shape) + (width,), np.uint8)
    out[..., -1] = 1
    return out


def merge_partials(
    parts: Sequence[tuple[np.ndarray, np.ndarray]], nsquare: int, backend: str | Backend | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """fpAdd of partial ray sums that share one exponent: ⊕ per ray, i.e. a product mod n².

    ``parts`` are ``(rays (R,), records (R, K, W))``; the result has sorted unique rays.
    Rays present in one part only are passed through without any arithmetic; the records
    of the others are converted once and multiplied per ray by the backend.
    """
    parts = [p for p in parts if p[0].size]
    if not parts:
        return np.zeros(0, np.int64), np.zeros((0, 0, 0), np.uint8)
    if len(parts) == 1:
        return parts[0]
    rays = np.concatenate([p[0] for p in parts])
    recs = np.concatenate([p[1] for p in parts])
    order = np.argsort(rays, kind="stable")
    rays, recs = rays[order], recs[order]
    uniq, start, counts = np.unique(rays, return_index=True, return_counts=True)
    out = recs[start].copy()
    multi = np.nonzero(counts > 1)[0]
    if multi.size:
        be = get_backend(backend)
        _, K, W = recs.shape
        rows = np.concatenate([np.arange(start[u], start[u] + counts[u]) for u in multi.tolist()])
        indptr = np.concatenate([[0], np.cumsum(counts[multi])])
        vals = be.from_bytes(recs[rows].reshape(-1, W))
        out[multi] = be.to_bytes(be.segment_products(vals, indptr, K, nsquare), W).reshape(-1, K, W)
    return uniq, out


def finish_tile(
    plan: RenderPlan,
    merged: tuple[np.ndarray, np.ndarray],
    pixels: np.ndarray,
    n_samples: np.ndarray,
    n: int,
    width_bytes: int,
    backend: str | Backend | None = None,
) -> np.ndarray:
    """(P, W) uint8 packed ciphertexts of one tile, for its hit pixels in (pixel, channel) order.

    ``merged`` holds the tile's merged ray sums ``(rays (R,), records (R, K, W))`` (rays sorted,
    global pixel indices); ``pixels`` and ``n_samples`` list every pixel of the tile.
    """
    be = get_backend(backend)
    rays, recs = merged
    recips = plan.reciprocal(n_samples)
    hit = np.flatnonzero(np.asarray(recips, dtype=object) != 0)
    if hit.size == 0:
        return np.zeros((0, width_bytes), np.uint8)
    C = plan.channels_out
    K = C if plan.comb is None else len(plan.comb)  # X-ray or client finishing: every component is a value
    sums = one_records((hit.size, K), width_bytes)
    if rays.size:
        want = np.asarray(pixels)[hit]
        pos = np.minimum(np.searchsorted(rays, want), rays.size - 1)
        found = rays[pos] == want
        sums[found] = recs[pos[found]]
    vals = be.from_bytes(sums.reshape(-1, width_bytes))
    nsquare = int(n) * int(n)
    terms = vals if plan.comb is None else be.combine(vals, plan.comb, nsquare)
    exps = [int(recips[i]) for i in hit.tolist() for _ in range(C)]
    packed = be.pack(terms, exps, plan.pack_bits, plan.per_pack, plan.offset, n)
    return be.to_bytes(packed, width_bytes)
