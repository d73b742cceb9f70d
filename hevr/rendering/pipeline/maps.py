"""The map tasks of a render: one brick's partial ray sums, or those of a worker's group of
resident bricks (:func:`map_group`), split by image tile as compact records.

A map task casts its footprint's rays (:mod:`hevr.rendering.geometry.footprint`), computes the plaintext
weights, takes its bricks from worker memory (resident) or reads them inside the task, runs the
encrypted kernel (:func:`hevr.rendering.pipeline.kernel.brick_ray_products_multi`) and emits, per image tile,
ray ids and fixed-width ciphertext records. :mod:`hevr.rendering.pipeline.graph` wires them into the graph.
"""

from __future__ import annotations

import time
from typing import Any

import dask
import numpy as np

from ...backends import get_backend
from ...crypto.tags import data_channel
from ...image.tiles import TileLayout
from ...runtime import malloc, stats
from ...store.reader import EncryptedVolume
from ..geometry.camera import Camera
from ..geometry.footprint import Footprint
from ..geometry.group_weights import nearest_group_rows
from ..geometry.rays import cast_rays
from ..geometry.weights import brick_weights
from .finishing import merge_partials
from .kernel import brick_ray_products_multi

__all__ = ["map_brick", "map_group", "resident_groups"]


def map_brick(
    ev: EncryptedVolume,
    camera: Camera,
    index: tuple[int, int, int],
    sampling: str,
    step: float,
    digits: int,
    channel: str,
    footprint: Footprint,
    tile: int,
    backend: str = "cpu",
    data: Any = None,
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """One map task: partial encrypted ray sums of one brick, split by tile.

    Casts only the rays of the brick's footprint rectangle (bit-identical to the same rays of
    the whole image), so its geometry costs the rectangle's pixels plus the samples that reach
    the brick. ``data`` is the brick's resident ciphertexts (:class:`ResidentBrick`, from
    :meth:`hevr.EncryptedVolume.persist`); without it the brick is read from the store.
    """
    malloc.tune()
    t0 = time.perf_counter()
    rays = cast_rays(camera, ev.shape, ev.spacing, step, pixels=footprint.pixels(camera.width))
    bw = brick_weights(rays, ev.shape, ev.spacing, ev.brick, index, sampling, step, digits)
    stats.add("map.geometry", time.perf_counter() - t0, 1)
    W = ev.meta.ciphertext_bytes
    tiles = footprint.tiles
    empty = (np.zeros(0, np.int64), np.zeros((0, ev.meta.components(channel), W), np.uint8))
    if bw.rays.size == 0:
        return {t: empty for t in tiles}
    be = get_backend(backend)
    if data is not None:
        cts = data.channel(channel)
    else:
        with stats.timed("map.read"):
            cts = ev.read_brick(index, channel, backend=be)
    comps = [cts] if data_channel(channel) == "scalar" else cts
    with stats.timed("map.kernel", int(bw.indptr[-1]) * len(comps)):
        prods = brick_ray_products_multi(comps, bw.indptr, bw.voxels, bw.weights, ev.public_key.nsquare, backend=be)
    return _emit(prods, bw.rays, be, W, camera, tile, tiles, f"brick {index}")


def _emit(
    prods: list, rays: np.ndarray, be: Any, width: int, camera: Camera, tile: int, tiles: Any, what: str
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """A map task's output: the products of ``rays`` (one batch per component) as records,
    split by image tile (every tile of ``tiles`` present, possibly empty)."""
    t0 = time.perf_counter()
    recs = np.stack([be.to_bytes(p, width) for p in prods], axis=1)  # (R, K, W)
    stats.add("map.emit", time.perf_counter() - t0)
    return _by_tile(rays, recs, camera, tile, tiles, what)


def _by_tile(
    rays: np.ndarray, recs: np.ndarray, camera: Camera, tile: int, tiles: Any, what: str
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Records of ``rays`` split by image tile (every tile of ``tiles`` present, possibly empty)."""
    t0 = time.perf_counter()
    tid = TileLayout(camera.width, camera.height, tile).ids(rays)
    out = {}
    for t in tiles:
        m = tid == t
        out[t] = (rays[m], recs[m])
    stats.add("map.emit", time.perf_counter() - t0)
    extra = set(np.unique(tid).tolist()) - set(tiles)
    if extra:  # pragma: no cover - footprint tiles hold every hit pixel of the rectangle
        raise RuntimeError(f"{what}: rays in tiles {sorted(extra)} not planned")
    return out


def map_group(
    ev: EncryptedVolume,
    camera: Camera,
    items: list,
    sampling: str,
    step: float,
    digits: int,
    channel: str,
    tile: int,
    backend: str,
    *data: Any,
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """One map task for several resident bricks of one worker, with one output per tile, so
    that the per-task overhead and the merge tasks scale with workers, not bricks.

    Nearest sampling: one product plan over the whole group — a row per ray holding its pairs in
    all the group's bricks (:func:`~hevr.rendering.geometry.group_weights.nearest_group_rows`), over the
    concatenation of the bricks' ciphertexts — so each ray's partial sum of the group comes out
    of one multi-exponentiation, and neither per-brick plans nor in-task merges are needed.
    Trilinear: each brick's :func:`map_brick`, then every tile's partials merged here.

    ``items`` lists ``(index, footprint)`` per brick, ``data`` their :class:`ResidentBrick`
    in the same order. The output is the same kind of dict by tile as :func:`map_brick`'s, with
    every tile of any of the bricks' footprints.
    """
    malloc.tune()
    W, K = ev.meta.ciphertext_bytes, ev.meta.components(channel)
    empty = (np.zeros(0, np.int64), np.zeros((0, K, W), np.uint8))
    tiles = sorted({t for _, fp in items for t in fp.tiles})
    n2 = int(ev.public_key.nsquare)
    if sampling == "nearest":
        t0 = time.perf_counter()
        pixels = np.unique(np.concatenate([fp.pixels(camera.width) for _, fp in items]))
        rays = cast_rays(camera, ev.shape, ev.spacing, step, pixels=pixels)
        rows = nearest_group_rows(rays, ev.shape, ev.spacing, ev.brick, [idx for idx, _ in items], step)
        sizes = [int(np.prod(ev.brick_shape(idx))) for idx, _ in items]
        voxels = rows.voxels(sizes)
        stats.add("map.geometry", time.perf_counter() - t0, len(items))
        if not rows.rays.size:
            return {t: empty for t in tiles}
        be = get_backend(backend)
        batches = [d.channel(channel) for d in data]
        comps = (
            [be.concat(batches)]
            if data_channel(channel) == "scalar"
            else [be.concat([b[c] for b in batches]) for c in range(K)]
        )
        with stats.timed("map.kernel", int(rows.indptr[-1]) * K):
            prods = brick_ray_products_multi(comps, rows.indptr, voxels, rows.weights, n2, backend=be)
        return _emit(prods, rows.rays, be, W, camera, tile, tiles, f"bricks {[idx for idx, _ in items]}")
    parts: dict[int, list] = {}
    per_brick = (
        _fused_bricks(ev, camera, items, sampling, step, digits, channel, tile, backend, data)
        if get_backend(backend).residence == "device"
        else (
            map_brick(ev, camera, idx, sampling, step, digits, channel, fp, tile, backend, brick)
            for (idx, fp), brick in zip(items, data)
        )
    )
    for out in per_brick:
        for t, part in out.items():
            if part[0].size:
                parts.setdefault(t, []).append(part)
    with stats.timed("map.merge", len(tiles)):
        return {
            t: (
                parts[t][0]
                if len(parts.get(t, ())) == 1
                else merge_partials(parts[t], n2, backend)
                if t in parts
                else empty
            )
            for t in tiles
        }


def _fused_bricks(
    ev: EncryptedVolume,
    camera: Camera,
    items: list,
    sampling: str,
    step: float,
    digits: int,
    channel: str,
    tile: int,
    backend: str,
    data: tuple,
) -> list[dict]:
    """Trilinear map of a group on a GPU: each brick's rows (its own :func:`brick_weights`, as
    :func:`map_brick` makes them) in one plan over the concatenation of the group's ciphertexts,
    so the device runs one launch for the group rather than one per brick in turn; then each
    brick's rows split by tile as :func:`map_brick` splits them. Every row's product is the same
    residue either way, so the image is byte for byte the per-brick one."""
    t0 = time.perf_counter()
    rows, indptr, voxels, weights, at_v, at_p = [], [np.zeros(1, np.int64)], [], [], 0, 0
    for idx, fp in items:
        rays = cast_rays(camera, ev.shape, ev.spacing, step, pixels=fp.pixels(camera.width))
        bw = brick_weights(rays, ev.shape, ev.spacing, ev.brick, idx, sampling, step, digits)
        rows.append((bw.rays, fp.tiles, idx))
        indptr.append(np.asarray(bw.indptr[1:], np.int64) + at_p)
        voxels.append(np.asarray(bw.voxels, np.int64) + at_v)
        weights.append(np.asarray(bw.weights))
        at_v += int(np.prod(ev.brick_shape(idx)))
        at_p += int(bw.indptr[-1])
    stats.add("map.geometry", time.perf_counter() - t0, len(items))
    W, K = ev.meta.ciphertext_bytes, ev.meta.components(channel)
    be = get_backend(backend)
    batches = [d.channel(channel) for d in data]
    comps = (
        [be.concat(batches)]
        if data_channel(channel) == "scalar"
        else [be.concat([b[c] for b in batches]) for c in range(K)]
    )
    ip = np.concatenate(indptr)
    recs = np.zeros((0, K, W), np.uint8)
    if ip[-1]:
        with stats.timed("map.kernel", int(ip[-1]) * K):
            prods = brick_ray_products_multi(
                comps, ip, np.concatenate(voxels), np.concatenate(weights), int(ev.public_key.nsquare), backend=be
            )
        recs = np.stack([be.to_bytes(p, W) for p in prods], axis=1)  # (R, K, W): every brick's rows in turn
    out, r0 = [], 0
    for ray_ids, tiles, idx in rows:
        out.append(_by_tile(ray_ids, recs[r0 : r0 + ray_ids.size], camera, tile, tiles, f"brick {idx}"))
        r0 += ray_ids.size
    return out


def resident_groups(resident: dict, client: Any, backend: str = "cpu") -> list[list]:
    """The resident bricks' indices grouped by the worker holding them (on a cluster), else
    into as many slabs (runs of raster order) as the local scheduler has threads — or one, where
    the backend's residues are on a GPU (this process's one device: one launch over all rays beats
    several small ones); brick order kept in each group."""
    keys = list(resident)
    if client is not None:
        futures = [resident[k] for k in keys]
        where = client.who_has(futures)
        by: dict[str, list] = {}
        for k, f in zip(keys, futures):
            holders = sorted(where.get(f.key, ())) or ["?"]
            by.setdefault(holders[0], []).append(k)
        return [by[w] for w in sorted(by)]
    n = 1 if get_backend(backend).residence == "device" else max(1, min(len(keys), dask.system.CPU_COUNT))
    return [keys[i * len(keys) // n : (i + 1) * len(keys) // n] for i in range(n)] if keys else []
