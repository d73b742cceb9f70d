"""The MapReduce render graph on Dask (after Stuart et al.).

map     one task per brick that some ray touches: read the brick's chunk inside the task,
        compute its plaintext weights, run the encrypted kernel, and emit partial ray sums
        split by image tile, as compact bytes (ray ids + fixed-width ciphertext records).
reduce  per image tile, a tree of merges (fan-in 4) multiplies the partials of the same
        ray (fpAdd of partial sums that share one exponent); no task receives every partial.
finish  per tile: per-pixel combination, reciprocal normalisation, offset and packing.

The graph holds public data only (the volume handle, camera, plan) and the *name* of the
arithmetic backend; every task resolves the backend in its own process
(:func:`hevr.backends.get_backend`), and converts bytes to the backend's form once.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import dask
import numpy as np

from .. import _stats
from .._tiles import TileLayout
from ..backends import get_backend
from ..store.reader import EncryptedVolume
from .camera import Camera
from .finishing import finish_tile, merge_partials
from .kernel import brick_ray_products_multi
from .planner import RenderPlan
from .rays import RaySet, cast_rays
from .weights import brick_weights, touched_bricks

log = logging.getLogger(__name__)

FAN_IN = 4


def conservative_tiles(rays: RaySet, ev: EncryptedVolume, index: tuple[int, int, int], tile: int) -> list[int]:
    """Tiles whose rays may touch a brick: slab test against the brick grown by one voxel."""
    sl = ev.brick_slices(index)
    sp = np.asarray(ev.spacing)  # (sx, sy, sz)
    lo_idx = np.array([sl[2].start, sl[1].start, sl[0].start], float) - 1.0
    hi_idx = np.array([sl[2].stop - 1, sl[1].stop - 1, sl[0].stop - 1], float) + 1.0
    lo, hi = lo_idx * sp, hi_idx * sp
    hit = np.nonzero(rays.n_samples > 0)[0]
    if hit.size == 0:
        return []
    o, d = rays.origins[hit], rays.directions[hit]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = (lo - o) * inv, (hi - o) * inv
    tmin = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
    tmax = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
    parallel_out = (d == 0) & ((o < lo) | (o > hi))
    t0 = np.maximum(tmin.max(axis=1), rays.t_enter[hit] - 1e-6)
    t3 = np.minimum(tmax.min(axis=1), rays.t_exit[hit] + 1e-6)
    ok = (t0 <= t3) & ~parallel_out.any(axis=1)
    return sorted(set(TileLayout(rays.width, rays.height, tile).ids(hit[ok]).tolist()))


def map_brick(ev: EncryptedVolume, camera: Camera, index: tuple[int, int, int], sampling: str, step: float,
              digits: int, channel: str, tiles: list[int], tile: int,
              backend: str = "cpu") -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """One map task: partial encrypted ray sums of one brick, split by tile."""

    t0 = time.perf_counter()
    rays = cast_rays(camera, ev.shape, ev.spacing, step)
    bw = brick_weights(rays, ev.shape, ev.spacing, ev.brick, index, sampling, step, digits)
    _stats.add("map.geometry", time.perf_counter() - t0, 1)
    W = ev.meta.ciphertext_bytes
    empty = (np.zeros(0, np.int64), np.zeros((0, 1 if channel == "scalar" else ev.vector_dims, W), np.uint8))
    if bw.rays.size == 0:
        return {t: empty for t in tiles}
    be = get_backend(backend)
    with _stats.timed("map.read"):
        cts = ev.read_brick(index, channel, backend=be)
    comps = [cts] if channel == "scalar" else cts
    with _stats.timed("map.kernel", int(bw.indptr[-1]) * len(comps)):
        prods = brick_ray_products_multi(comps, bw.indptr, bw.voxels, bw.weights, ev.public_key.nsquare, backend=be)
    t0 = time.perf_counter()
    recs = np.stack([be.to_bytes(p, W) for p in prods], axis=1)  # (R, C, W)
    tid = TileLayout(rays.width, rays.height, tile).ids(bw.rays)
    out = {}
    for t in tiles:
        m = tid == t
        out[t] = (bw.rays[m], recs[m])
    _stats.add("map.emit", time.perf_counter() - t0)
    extra = set(np.unique(tid).tolist()) - set(tiles)
    if extra:  # pragma: no cover - the slab test is conservative
        raise RuntimeError(f"brick {index}: rays in tiles {sorted(extra)} not planned")
    return out


def merge_task(nsquare: int, backend: str, *parts):
    """One merge task: ⊕ per ray of up to ``FAN_IN`` partial results of one tile."""
    with _stats.timed("merge", 1):
        return merge_partials(parts, nsquare, backend)


def finish_task(plan: RenderPlan, merged: tuple[np.ndarray, np.ndarray], pixels: np.ndarray,
                n_samples: np.ndarray, n: int, width_bytes: int, backend: str = "cpu") -> np.ndarray:
    """One finish task: (P, W) uint8 packed ciphertexts of one tile."""
    with _stats.timed("finish", 1):
        return finish_tile(plan, merged, pixels, n_samples, n, width_bytes, backend)


def build_sums_graph(ev: EncryptedVolume, camera: Camera, rays: RaySet, sampling: str, step: float, digits: int,
                     channel: str, tile: int, n_tiles: int, backend: str = "cpu") -> tuple[dict[int, Any], int]:
    """Delayed merged ray sums per tile (None for tiles no brick touches); map task count."""

    bricks = touched_bricks(rays, ev.shape, ev.spacing, ev.brick, sampling, step)
    token = dask.base.tokenize(ev.path, ev.meta.fingerprint, camera.key(), sampling, step, digits, channel, tile)
    leaves: dict[int, list] = {t: [] for t in range(n_tiles)}
    n2 = int(ev.public_key.nsquare)
    for idx in bricks:
        tiles = conservative_tiles(rays, ev, idx, tile)
        if not tiles:
            continue
        name = f"hevr-map-{token}-{idx[0]}-{idx[1]}-{idx[2]}"
        m = dask.delayed(map_brick, pure=True)(ev, camera, idx, sampling, step, digits, channel, tiles, tile,
                                               backend, dask_key_name=name)
        for t in tiles:
            leaves[t].append(m[t])
    merged: dict[int, Any] = {}
    for t, parts in leaves.items():
        level = 0
        while len(parts) > 1:
            parts = [dask.delayed(merge_task, pure=True)(n2, backend, *parts[i:i + FAN_IN],
                                                          dask_key_name=f"hevr-merge-{token}-{t}-{level}-{i}")
                     for i in range(0, len(parts), FAN_IN)]
            level += 1
        merged[t] = parts[0] if parts else None
    return merged, len(bricks)
