"""A packed store's slice: the Dask graph (map per column of bricks, merge per tile) and
:class:`PackedSlice`, the key holder's checks, decoding and finishing.

* **map** (one task per column of bricks along the packing axis, as packed frames): read the
  bricks' packed ciphertexts (or take them from a resident volume) and compute every output value's
  partial product Π Enc(P[A, b, c])^w over the footprint voxels in those bricks, one
  multi-exponentiation per value (:func:`~hevr.rendering.pipeline.kernel.plan_products` on the
  backend's ``ray_products``), cut by merge tile.
* **merge** (one task per tile of :data:`~hevr.rendering.packed.planes.TILE_VALUES` values): the
  product of the bricks' partials per value (a footprint can straddle bricks).

The key holder (:meth:`PackedSlice.decrypt`) checks every ciphertext (in (0, n²)) and every
plaintext (no bit above its S slots: the integrity margin; no slot above span·W of its footprint,
none at all in a layer past the volume's end) before any pixel is formed, then finishes the pixels
in float64 (:mod:`hevr.rendering.packed.planes`). A verifiable store's slice is verified as a
frame is (:func:`slice_verification`: a seed drawn after the values, the tags through the slice's
plan, one aggregate; the key holder's check before any pixel).
"""

from __future__ import annotations

import logging
import secrets
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import gmpy2
import numpy as np
from dask.delayed import delayed

from ...backends import get_backend
from ...backends.base import OpCounter
from ...crypto.keys import PrivateKey
from ...crypto.tags import tag_channel
from ...errors import IntegrityError, ParameterError
from ...image.provenance import check_provenance
from ...runtime.scheduler import compute as run_tasks
from ...store.packing import INTEGRITY_BITS, mantissa_range, unpack_slots
from ..pipeline.finishing import one_records
from ..pipeline.kernel import plan_products
from .graph import brick_columns, merge_parts, render_context, resident_bricks
from .image import check_key
from .planes import TILE_VALUES, PlanePlan
from .verified import PackedVerification, aggregate_tile

log = logging.getLogger(__name__)

__all__ = ["PackedSlice", "decode_slice", "render_packed_slice"]

_CORRUPT = "the slice was corrupted or tampered with; no image is returned"


def map_bricks(
    ev: Any,
    plan: Any,
    indices: list,
    backend: str,
    tiles: list[int],
    residents: list | None = None,
    channel: str = "scalar",
) -> tuple[list[tuple[np.ndarray, np.ndarray]], dict]:
    """The partial output values of bricks ``indices`` cut by the tiles ``tiles`` ((values, records)
    each, in that order), and the operations counted (``channel="scalar_tag"``: the tags')."""
    be = get_backend(backend)
    width = ev.meta.ciphertext_bytes
    batches = [
        r.batches[channel] if r is not None else ev.read_brick(idx, channel, backend=be)
        for idx, r in zip(indices, residents or [None] * len(indices))
    ]
    parts, off = [], 0
    for idx, batch in zip(indices, batches):
        v, loc, w = plan.brick_pairs(idx)
        parts.append((v, loc + off, w))
        off += len(batch)
    keys = np.concatenate([p[0] for p in parts])
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    local, weights = np.concatenate([p[1] for p in parts])[order], np.concatenate([p[2] for p in parts])[order]
    if not len(keys):
        return [(np.zeros(0, np.int64), np.zeros((0, width), np.uint8)) for _ in tiles], {"map": 0, "pairs": 0}
    batch = batches[0] if len(batches) == 1 else be.concat(batches)
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    uniq = keys[starts]
    counter = OpCounter()
    pp = plan_products(np.r_[starts, len(keys)].astype(np.int64), local, weights, len(batch))
    recs = be.to_bytes(be.ray_products(pp, [batch], int(ev.public_key.nsquare), counter)[0], width)
    where = uniq // TILE_VALUES
    return [(uniq[where == t], recs[where == t]) for t in tiles], {"map": counter.modmuls, "pairs": int(len(keys))}


def merge_values(plan: Any, t: int, n: int, width: int, backend: str, *parts: Any) -> tuple[np.ndarray, int]:
    """Tile ``t``'s output values, (values, W) records in value order, and the products spent."""
    be = get_backend(backend)
    v0, v1 = plan.tile_bounds(t)
    out = one_records((v1 - v0,), width)
    uniq, merged, ops = merge_parts(be, n, parts)
    if len(uniq):
        out[uniq - v0] = be.to_bytes(merged, width)
    return out, ops


def render_packed_slice(
    ev: Any,
    plane: Any,
    sampling: str = "nearest",
    *,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
) -> PackedSlice:
    """Render ``plane`` of a packed store (:func:`hevr.render_slice` routes here after its checks)."""
    cl, backend = render_context(ev, backend, client)
    meta = ev.meta
    plan = PlanePlan.build(plane, meta.shape, meta.spacing, meta.brick, meta.packing, sampling)
    t0 = time.perf_counter()
    lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
    if not plan.hits.any():
        log.warning(
            "render_slice: no pixel of this %dx%d plane meets the packed volume: the slice is empty",
            plane.width,
            plane.height,
        )
    resident = resident_bricks(ev, "scalar", backend, cl)
    n, width, plain = int(ev.public_key.n), meta.ciphertext_bytes, ev._plain()
    tag = f"{meta.store_id}-{uuid.uuid4().hex}"
    plan_d = delayed(plan, pure=True, name=f"hevr-packed-slice-plan-{tag}")  # one copy in the graph
    per_tile, maps = _map_graph(plain, plan, plan_d, backend, resident, "scalar", tag)
    fin = [
        delayed(merge_values, pure=True, nout=2)(
            plan_d, t, n, width, backend, *per_tile[t], dask_key_name=f"hevr-packed-slice-tile-{tag}-{t}"
        )
        for t in range(plan.n_tiles)
    ]
    results = run_tasks(fin + maps, client=cl, progress=progress, desc="slice")
    tiles_out = [r[0] for r in results[: len(fin)]]
    ops = {
        "map": sum(m["map"] for m in results[len(fin) :]),
        "pairs": sum(m["pairs"] for m in results[len(fin) :]),
        "merge": sum(r[1] for r in results[: len(fin)]),
    }
    stats = {
        "layout": "packed",
        "kind": plan.kind,
        "backend": backend,
        "map_tasks": len(maps),
        "finish_tasks": len(fin),
        "resident": resident is not None,
        "ops": ops,
        "footprints": plan.n_footprints,
        "ciphertexts": plan.n_values,
        "seconds": time.perf_counter() - t0,
    }
    log.info("slice packed/%s %dx%d (%s): %s", sampling, plane.width, plane.height, plan.kind, stats)
    return PackedSlice(
        plan=plan,
        plane=plane,
        fingerprint=meta.fingerprint,
        n=n,
        exponent=meta.scalar.exponent,
        offset=meta.packing.offset,
        span=hi - lo,
        ciphertexts=tiles_out,
        store_id=meta.store_id,
        stats=stats,
        tags=bool(meta.tags),
    )


def _map_graph(
    ev: Any, plan: PlanePlan, plan_d: Any, backend: str, resident: dict | None, channel: str, tag: str
) -> tuple[dict[int, list], list]:
    """The map tasks of a slice on ``channel``: per merge tile the delayed partial values that reach
    it, and every map task's operation counts (one task per column of bricks along the packing axis)."""
    per_tile: dict[int, list] = {t: [] for t in range(plan.n_tiles)}
    maps = []
    for column in brick_columns(ev.grid, plan.packing.axis):
        reach = {idx: plan.brick_tiles(idx) for idx in column}
        column = [idx for idx in column if reach[idx]]
        if not column:
            continue
        tiles = sorted(set().union(*(reach[idx] for idx in column)))
        name = f"hevr-packed-slice-map-{channel}-{tag}-{'-'.join(map(str, column[0]))}"
        task = delayed(map_bricks, pure=True, nout=2)(
            ev,
            plan_d,
            column,
            backend,
            tiles,
            [resident.get(i) for i in column] if resident is not None else None,
            channel,
            dask_key_name=name,
        )
        maps.append(task[1])
        for pos, t in enumerate(tiles):
            per_tile[t].append(task[0][pos])
    return per_tile, maps


def slice_aggregate(
    ev: Any, plan: PlanePlan, backend: str, client: Any, progress: bool, seed: bytes
) -> tuple[int, dict]:
    """The server's half of a slice's tags' round for ``seed``: the tags through the slice's plan,
    one aggregate per merge tile (A = Π_v T_v^ρ_v, the values' ids as indices:
    :func:`~hevr.rendering.packed.verified.aggregate_tile` with one class), their product."""
    meta = ev.meta
    if not meta.tags:
        raise ParameterError(f"verify: expected a verifiable store, got the packed store {meta.store_id} without tags")
    n, width = int(ev.public_key.n), meta.ciphertext_bytes
    tag = f"{meta.store_id}-{uuid.uuid4().hex}"
    plan_d = delayed(plan, pure=True, name=f"hevr-packed-slice-plan-{tag}")
    per_tile, maps = _map_graph(ev._plain(), plan, plan_d, backend, None, tag_channel("scalar"), tag)
    tasks = [
        delayed(aggregate_tile, pure=True, nout=2)(
            plan_d, t, n, width, backend, seed, 0, *per_tile[t], dask_key_name=f"hevr-packed-slice-verify-{tag}-{t}"
        )
        for t in range(plan.n_tiles)
        if per_tile[t]
    ]
    results = run_tasks(tasks + maps, client=client, progress=progress, desc="verify") if tasks else []
    A, n2 = gmpy2.mpz(1), gmpy2.mpz(n) * n
    for rec, _ in results[: len(tasks)]:
        if rec is not None:
            A = A * gmpy2.mpz(int.from_bytes(np.asarray(rec, np.uint8).tobytes(), "big")) % n2
    return int(A), {"map": sum(m["map"] for m in results[len(tasks) :])}


def slice_verification(ev: Any, plan: PlanePlan, backend: str, client: Any, progress: bool) -> PackedVerification:
    """The tags' round of a slice, after its values are in the key holder's hands: a fresh seed
    drawn here, then :func:`slice_aggregate`; the record to keep."""
    seed = secrets.token_bytes(32)
    t0 = time.perf_counter()
    A, ops = slice_aggregate(ev, plan, backend, client, progress, seed)
    return PackedVerification(
        aggregate=A,
        seed=seed,
        meta=ev.meta,
        ops=ops,
        server_s=time.perf_counter() - t0,
        drawn_here=True,
        drawn_at=time.time(),
        known_name=str(ev.path),
    )


@dataclass
class PackedSlice:
    """An encrypted slice of a packed store (``hevr.render_slice`` on a store with ``layout="packed"``).

    Attributes
    ----------
    plan : PlanePlan
        The slice's public plan (footprints, packs, the finishing terms).
    plane : Plane
    fingerprint, n :
        The key's fingerprint and modulus.
    exponent, offset, span : int
        The scalar channel's exponent, the store's slot offset (lowest mantissa) and mantissa span.
    ciphertexts : list of np.ndarray
        Per merge tile, (values, W) uint8 big-endian records.
    store_id : str
    stats : dict
        ``ops`` (map, pairs, merge), ``footprints``, ``ciphertexts``, ``kind``, …
    """

    plan: Any = field(repr=False)
    plane: Any = field(repr=False)
    fingerprint: str
    n: int = field(repr=False)
    exponent: int
    offset: int
    span: int
    ciphertexts: list = field(repr=False)
    store_id: str = ""
    stats: dict = field(default_factory=dict, repr=False)
    tags: bool | None = None  # whether the store carries tags (the key's policy: hevr.image.provenance)
    verification: Any = field(default=None, repr=False, compare=False)  # a PackedVerification, or None

    @property
    def shape(self) -> tuple[int, int]:
        return (self.plane.height, self.plane.width)

    @property
    def hits(self) -> np.ndarray:
        """(H, W) bool: the pixels with a sample inside the volume (public geometry)."""
        return self.plan.hits

    @property
    def n_ciphertexts(self) -> int:
        return int(sum(len(c) for c in self.ciphertexts))

    @property
    def verified(self) -> bool:
        """Whether the slice carries a check against the store's tags (drawn in this process)."""
        return self.verification is not None

    def decrypt_values(self, private_key: PrivateKey, backend: str | None = None) -> np.ndarray:
        """(V, S) int64: every output value's slots, Σ w·u per layer, after every check (:func:`decode_slice`)."""
        check_key(private_key, self.fingerprint, self.n, "slice")
        be = get_backend(backend)
        n2, width = int(private_key.public_key.nsquare), private_key.public_key.ciphertext_bytes
        if len(self.ciphertexts) != self.plan.n_tiles:
            raise IntegrityError(f"slice: expected {self.plan.n_tiles} tiles, got {len(self.ciphertexts)}; {_CORRUPT}")
        tiles = []
        for t, recs in enumerate(self.ciphertexts):
            recs = np.asarray(recs)
            v0, v1 = self.plan.tile_bounds(t)
            if recs.shape != (v1 - v0, width) or recs.dtype != np.uint8:
                raise IntegrityError(
                    f"slice: tile {t}: expected ({v1 - v0}, {width}) uint8 records, got {recs.shape} "
                    f"{recs.dtype}; {_CORRUPT}"
                )
            batch = be.from_bytes(recs)
            bad = be.first_out_of_range(batch, n2)
            if bad is not None:
                raise IntegrityError(f"slice: tile {t}: ciphertext {bad} is not in (0, n²); {_CORRUPT}")
            tiles.append(be.decrypt(private_key, batch))
        slots = decode_slice(self.plan, [int(v) for tile in tiles for v in tile], self.span)
        if self.verification is not None:  # every value against the tags before any pixel
            self.verification.check(private_key, self.plan, [tiles], self.fingerprint)
        return slots

    def decrypt(
        self, private_key: PrivateKey, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """The slice's float64 (H, W) pixels (the mean of each pixel's slab samples; 0 where none is
        inside, see :attr:`hits`), after every check (a verified slice: against the store's tags first);
        ``require_verified`` (True, or the store id that must have been proven) refuses an unverified one."""
        check_provenance(
            check_key(private_key, self.fingerprint, self.n, "slice"),
            self,
            require_verified,
            "a store without tags, or verify=False",
        )
        slots = self.decrypt_values(private_key, backend)
        plan = self.plan
        fp, _ = plan.value_layers()
        W = plan.weight_totals()[fp]  # per value: offset·W_F undoes the store's offset
        v = slots[plan.term_value, plan.term_slot]
        off, e = int(self.offset), int(self.exponent)
        if len(v) and abs(off) * int(W.max()) + int(v.max()) >= 1 << 53:  # pragma: no cover - huge float offsets
            total = np.array([float(int(x) + int(w) * off) for x, w in zip(v, W[plan.term_value])])
        else:
            total = v.astype(np.float64) + W[plan.term_value].astype(np.float64) * float(off)
        sums = np.zeros(plan.counts.shape, np.float64)
        np.add.at(sums, plan.term_pixel, plan.term_alpha * total)
        out = np.zeros_like(sums)
        hit = plan.counts > 0
        out[hit] = sums[hit] * 10.0**e / (plan.counts[hit] * float(plan.unit))
        return out.reshape(self.shape)

    def __repr__(self) -> str:
        return (
            f"PackedSlice(shape={self.shape}, kind={self.plan.kind!r}, sampling={self.plan.sampling!r}, "
            f"slots={self.plan.packing.slots}, ciphertexts={self.n_ciphertexts}, verified={self.verified}, "
            f"key={self.fingerprint[:16]}…)"
        )


def decode_slice(plan: PlanePlan, values: list[int], span: int) -> np.ndarray:
    """(V, S) int64 slot sums of the decrypted ``values`` (one per output value, in order).

    Raises :class:`hevr.IntegrityError` for a missing or extra value, a value with a bit set above
    its S slots (the integrity margin), a slot above span·W of its footprint, or a non-zero slot of a
    layer past the volume's end (the store holds 0 there)."""
    S, K = plan.packing.slots, plan.packing.slot_bits
    if len(values) != plan.n_values:
        raise IntegrityError(f"slice: expected {plan.n_values} values, got {len(values)}; {_CORRUPT}")
    limit = 1 << (S * K)
    if any(not 0 <= v < limit for v in values):
        raise IntegrityError(
            f"slice: a value has bits set above its {S} slots of {K} bits (the "
            f"{INTEGRITY_BITS}-bit integrity margin and more); {_CORRUPT}"
        )
    slots = unpack_slots(values, S, K).reshape(len(values), S)
    fp, first = plan.value_layers()
    top = (plan.weight_totals()[fp] * int(span))[:, None] * np.ones((1, S), np.int64)
    top[first[:, None] + np.arange(S)[None, :] >= plan.shape[plan.packing.axis]] = 0
    if (slots > top).any():
        raise IntegrityError(f"slice: a slot is above the largest sum its footprint can have; {_CORRUPT}")
    return slots
