"""A packed store's frame as one Dask graph: map per brick, merge and combine per tile.

* **map** (one task per column of bricks along the view's principal axis, at most
  :data:`COLUMN_BRICKS`): read the bricks' packed ciphertexts (or take them from a resident
  volume, :meth:`hevr.EncryptedVolume.persist`), and compute every accumulator they contribute
  to, Π Enc(P[A])^w, as one multi-exponentiation per accumulator over all the column's slices
  (:func:`~hevr.rendering.pipeline.kernel.plan_products` on the backend: equal weights grouped,
  buckets over distinct weights). Its output is cut by reduce tile.
* **merge and combine** (one task per tile of the intermediate image: ``tile`` rows × ``tile // S``
  blocks): the product of the bricks' partial accumulators with equal keys, then per (B, j) the
  Horner combine of its classes (the backend's ``pack`` with exponents 1 and base 2^K).

Modular operations are counted (map: the backend's :class:`~hevr.backends.base.OpCounter`;
merge: one product per extra partial; combine: K·O squarings and O products per value) and
reported in the image's ``stats``.
"""

from __future__ import annotations

import logging
import time
import uuid
from typing import Any

import numpy as np
from dask.delayed import delayed

from ...backends import get_backend, resolve_backend_name
from ...backends.base import OpCounter
from ...runtime.scheduler import active_client, warn_if_remote
from ...runtime.scheduler import compute as run_tasks
from ...store.packing import mantissa_range
from ...store.paths import check_reachable
from ..pipeline.finishing import one_records
from ..pipeline.kernel import plan_products
from .image import PackedImage
from .plan import SlicePlan

log = logging.getLogger(__name__)

__all__ = ["brick_columns", "column_pairs", "map_column", "merge_tile", "render_packed"]


def column_pairs(plan: SlicePlan, indices: list, sizes: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs of a column of bricks (:meth:`SlicePlan.brick_pairs`), their local packs offset
    into the concatenation of the bricks' batches (``sizes``: packs per brick), sorted by key."""
    parts, off = [], 0
    for idx, size in zip(indices, sizes):
        k, loc, w = plan.brick_pairs(idx)
        parts.append((k, loc + off, w))
        off += size
    keys = np.concatenate([p[0] for p in parts])
    order = np.argsort(keys, kind="stable")
    return keys[order], np.concatenate([p[1] for p in parts])[order], np.concatenate([p[2] for p in parts])[order]


def map_column(
    ev: Any,
    plan: SlicePlan,
    indices: list,
    backend: str,
    tiles: list[int],
    residents: list | None = None,
    channel: str = "scalar",
) -> tuple[list[tuple[np.ndarray, np.ndarray]], dict]:
    """The partial accumulators of a column of bricks along the view's principal axis, cut by the
    tiles ``tiles``: a list of (keys, records) in that order, and the operations counted. One
    product plan for the column: an accumulator's pairs from all its slices in one
    multi-exponentiation (about 4·N_p/S pairs, not 4·brick/S: fewer operations per pair).
    ``channel``: ``"scalar"``, or its tags ``"scalar_tag"`` (the same products, :mod:`.verified`)."""
    be = get_backend(backend)
    width = ev.meta.ciphertext_bytes
    batches = [
        r.batches[channel] if r is not None else ev.read_brick(idx, channel, backend=be)
        for idx, r in zip(indices, residents or [None] * len(indices))
    ]
    keys, local, weights = column_pairs(plan, indices, [len(b) for b in batches])
    empty = (np.zeros(0, np.int64), np.zeros((0, width), np.uint8))
    if not len(keys):
        return [empty for _ in tiles], {"map": 0, "pairs": 0}
    batch = batches[0] if len(batches) == 1 else be.concat(batches)
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    uniq = keys[starts]
    indptr = np.r_[starts, len(keys)].astype(np.int64)
    counter = OpCounter()
    pp = plan_products(indptr, local, weights, len(batch))
    values = be.ray_products(pp, [batch], int(ev.public_key.nsquare), counter)[0]
    recs = be.to_bytes(values, width)
    where = plan.tile_of(uniq)
    parts = [(uniq[where == t], recs[where == t]) for t in tiles]
    if sum(len(k) for k, _ in parts) != len(uniq):  # pragma: no cover - brick_tiles is a superset by construction
        raise AssertionError("packed map: a product fell outside the brick's tiles")
    return parts, {"map": counter.modmuls, "pairs": int(len(keys))}


def merge_parts(be: Any, n: int, parts: Any) -> tuple[np.ndarray, Any, int]:
    """The product per key of the bricks' partial accumulators ``parts`` ((keys, records) each):
    the sorted distinct keys, their merged residues (the backend's form) and the products spent."""
    keys = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
    if not len(keys):
        return keys, None, 0
    recs = np.concatenate([p[1] for p in parts])
    order = np.argsort(keys, kind="stable")
    keys, recs = keys[order], recs[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    merged = be.segment_products(be.from_bytes(recs), np.r_[starts, len(keys)].astype(np.int64), 1, n * n)
    return keys[starts], merged, len(keys) - len(starts)


def merge_tile(plan: SlicePlan, t: int, n: int, width: int, backend: str, *parts: Any) -> tuple[np.ndarray, dict]:
    """Tile ``t``: the product of the bricks' partial accumulators per key, then the Horner
    combine of every (B, j)'s classes; returns the tile's (values, W) records, (j, B) row-major."""
    be = get_backend(backend)
    j0, j1, b0, b1 = plan.tile_bounds(t)
    nb, C = b1 - b0, plan.classes
    n_acc = (j1 - j0) * nb * C
    full = one_records((n_acc,), width)
    uniq, merged, merged_ops = merge_parts(be, n, parts)
    if len(uniq):
        # global key -> the tile's accumulator index (rows j, blocks B, classes), row-major
        acc, c = uniq // C, uniq % C
        jr, br = acc // plan.n_blocks - j0, acc % plan.n_blocks - b0
        full[(jr * nb + br) * C + c] = be.to_bytes(merged, width)
    out = be.pack(be.from_bytes(full), [1] * n_acc, plan.packing.slot_bits, C, 0, n)
    n_out = (j1 - j0) * nb
    K, o_max = plan.packing.slot_bits, C - 1
    ops = {"merge": merged_ops, "combine_squarings": n_out * K * o_max, "combine": n_out * o_max}
    return be.to_bytes(out, width), ops


COLUMN_BRICKS = 16  # bricks of one map task at most (a column along the principal axis, in pieces)


def brick_columns(grid: tuple[int, int, int], axis: int, most: int = COLUMN_BRICKS) -> list[list[tuple[int, ...]]]:
    """The brick indices in columns along ``axis`` (pieces of at most ``most`` bricks): one map task each.

    >>> brick_columns((2, 1, 3), 2, 2)
    [[(0, 0, 0), (0, 0, 1)], [(0, 0, 2)], [(1, 0, 0), (1, 0, 1)], [(1, 0, 2)]]
    """
    out: list[list[tuple[int, ...]]] = []
    others = [ax for ax in range(3) if ax != axis]
    for a in range(grid[others[0]]):
        for b in range(grid[others[1]]):
            col = []
            for k in range(grid[axis]):
                idx = [0, 0, 0]
                idx[others[0]], idx[others[1]], idx[axis] = a, b, k
                col.append(tuple(idx))
            out.extend(col[i : i + most] for i in range(0, len(col), most))
    return out


def map_graph(
    ev: Any, plan: SlicePlan, backend: str, resident: dict | None, channel: str, tag: str, fn: Any = None
) -> tuple[dict[int, list], list]:
    """The map tasks of a frame on ``channel``: per tile the delayed partial accumulators that
    reach it, and every map task's operation counts (one task per column of bricks). ``fn``: the
    map task, called as :func:`map_column` is (default; the colour frames' k components:
    :func:`~hevr.rendering.packed.colour.map_components`)."""
    per_tile: dict[int, list] = {t: [] for t in range(plan.n_tiles)}
    maps = []
    for column in brick_columns(ev.grid, plan.geometry.principal):
        reach = {idx: plan.brick_tiles(idx) for idx in column}
        column = [idx for idx in column if reach[idx]]
        if not column:
            continue
        tiles = sorted(set().union(*(reach[idx] for idx in column)))
        idx = column[0]
        name = f"hevr-packed-map-{channel}-{tag}-{idx[0]}-{idx[1]}-{idx[2]}"
        task = delayed(fn or map_column, pure=True, nout=2)(
            ev,
            plan,
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


def render_context(ev: Any, backend: str | None, client: Any) -> tuple[Any, str]:
    """The Dask client of a packed render (the given or active one; a remote scheduler warned of,
    the store reachable from its workers) and the backend's name (the residency's, else by key)."""
    cl = active_client(client)
    warn_if_remote(cl)
    check_reachable(ev.path, cl)
    res = ev.resident.backend if ev.resident is not None and ev.resident.bricks else None
    return cl, resolve_backend_name(backend, int(ev.public_key.n).bit_length(), resident=res, client=cl)


def resident_bricks(ev: Any, channel: str, backend: str, client: Any) -> dict | None:
    """The resident bricks that can serve ``channel`` on ``backend`` (None: stream from the store,
    said when a residency exists but cannot serve)."""
    if ev.resident is None or not ev.resident.bricks:
        return None
    if ev.resident.usable(channel, backend, client):
        return ev.resident.bricks
    log.warning(
        "render: the resident bricks cannot serve this render (backend %s, the %s channel); streaming from the store",
        backend,
        channel,
    )
    return None


def render_packed(
    ev: Any,
    camera: Any,
    sampling: str,
    *,
    tile: int = 32,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    weight_bits: int | None = None,
) -> PackedImage:
    """Render a packed store's X-ray of a parallel ``camera`` (:func:`hevr.render` routes here;
    its request checks are done there)."""
    cl, backend = render_context(ev, backend, client)
    t0 = time.perf_counter()
    meta = ev.meta
    plan = SlicePlan.of_store(meta, camera, sampling, tile, weight_bits)  # its slots checked before any work
    lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
    if plan.n_tiles == 0:  # public geometry: say so rather than hand back a black frame
        log.warning(
            "render: no ray of this %dx%d camera hits the packed volume: the image is empty; aim it at the "
            "volume (hevr.Camera.orbit looks at its centre)",
            camera.width,
            camera.height,
        )
    resident = resident_bricks(ev, "scalar", backend, cl)
    n = int(ev.public_key.n)
    width = meta.ciphertext_bytes
    plain = ev._plain()
    tag = f"{meta.store_id}-{uuid.uuid4().hex}"  # this render's tasks (never another render's results)
    per_tile, maps = map_graph(plain, plan, backend, resident, "scalar", tag)
    fin = [
        delayed(merge_tile, pure=True, nout=2)(
            plan, t, n, width, backend, *per_tile[t], dask_key_name=f"hevr-packed-tile-{tag}-{t}"
        )
        for t in range(plan.n_tiles)
    ]
    results = run_tasks([f for f in fin] + maps, client=cl, progress=progress, desc="render")
    tiles_out = [r[0] for r in results[: len(fin)]]
    counts = {"map": sum(m["map"] for m in results[len(fin) :]), "pairs": sum(m["pairs"] for m in results[len(fin) :])}
    for r in results[: len(fin)]:
        for k, v in r[1].items():
            counts[k] = counts.get(k, 0) + v
    stats = {
        "layout": "packed",
        "backend": backend,
        "map_tasks": len(maps),
        "finish_tasks": len(fin),
        "resident": resident is not None,
        "ops": counts,
        "rays": int(np.prod(plan.geometry.size)),
        "ciphertexts": int(sum(len(t) for t in tiles_out)),
        "seconds": time.perf_counter() - t0,
    }
    log.info("render packed/%s %dx%d: %s", sampling, camera.width, camera.height, stats)
    return PackedImage(
        plan=plan,
        camera=camera,
        fingerprint=meta.fingerprint,
        n=n,
        exponent=meta.scalar.exponent,
        offset=meta.packing.offset,
        span=hi - lo,
        ciphertexts=tiles_out,
        store_id=meta.store_id,
        stats=stats,
        meta=ev.base if getattr(ev, "level", 0) else meta,
        level=int(getattr(ev, "level", 0)),
    )
