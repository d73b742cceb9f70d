"""The MapReduce render graph on Dask (after Stuart et al.).

map     one task per brick whose footprint (:mod:`hevr.rendering.footprint`) holds a hit
        pixel: cast the footprint's rays, compute the brick's plaintext weights, read the
        brick inside the task (or take it from worker memory when the volume is resident),
        run the encrypted kernel, and emit partial ray sums split by image tile, as compact
        bytes (ray ids + fixed-width ciphertext records).
reduce  per image tile, a tree of merges (fan-in 4) multiplies the partials of the same
        ray (fpAdd of partial sums that share one exponent); no task receives every partial.
finish  per tile: per-pixel combination, reciprocal normalisation, offset and packing.

Resident bricks below 1024-bit keys are mapped one task per worker (:func:`map_group`); every
tile then has at most one partial per worker, and merge and finish run in one task per block of
tiles instead (:mod:`hevr.rendering.reduce`).

The graph holds public data only (the volume handle, camera, plan) and the *name* of the
arithmetic backend; every task resolves the backend in its own process
(:func:`hevr.backends.get_backend`), and converts bytes to the backend's form once.
"""

from __future__ import annotations

import logging
import operator
import time
import uuid
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import dask
import numpy as np
from dask.delayed import Delayed
from dask.highlevelgraph import HighLevelGraph, MaterializedLayer

from .. import _malloc, _stats
from .._tiles import TileLayout
from ..backends import get_backend
from ..crypto.records import record_width
from ..crypto.tags import data_channel
from ..store.reader import EncryptedVolume
from .camera import Camera
from .finishing import finish_tile, finish_units, merge_partials
from .footprint import Footprint, brick_footprints
from .group_weights import nearest_group_rows
from .kernel import brick_ray_products_multi
from .planner import RenderPlan
from .rays import RaySet, cast_rays
from .weights import brick_weights

log = logging.getLogger(__name__)

FAN_IN = 4
FOLLOW_UP = 1 << 40  # priority of everything after a map task: run as soon as it is ready


class Priorities:
    """Dask task priorities of a layer (higher runs first): ``key -> value``, else ``default``.

    Map tasks go in image order (by their footprint's first row), so the tiles at the top
    complete first; everything after a map task outranks the maps still waiting, so merging
    and finishing overlap the map phase instead of forming a tail.

    >>> Priorities({"a": 3}, 7)("a"), Priorities({"a": 3}, 7)("b")
    (3, 7)
    """

    def __init__(self, values: dict, default: int = FOLLOW_UP) -> None:
        self.values, self.default = values, default

    def __call__(self, key: Any) -> int:
        return self.values.get(key, self.default)


def map_brick(ev: EncryptedVolume, camera: Camera, index: tuple[int, int, int], sampling: str, step: float,
              digits: int, channel: str, footprint: Footprint, tile: int,
              backend: str = "cpu", data: Any = None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """One map task: partial encrypted ray sums of one brick, split by tile.

    Casts only the rays of the brick's footprint rectangle (bit-identical to the same rays of
    the whole image), so its geometry costs the rectangle's pixels plus the samples that reach
    the brick. ``data`` is the brick's resident ciphertexts (:class:`ResidentBrick`, from
    :meth:`hevr.EncryptedVolume.persist`); without it the brick is read from the store.
    """
    _malloc.tune()
    t0 = time.perf_counter()
    rays = cast_rays(camera, ev.shape, ev.spacing, step, pixels=footprint.pixels(camera.width))
    bw = brick_weights(rays, ev.shape, ev.spacing, ev.brick, index, sampling, step, digits)
    _stats.add("map.geometry", time.perf_counter() - t0, 1)
    W = ev.meta.ciphertext_bytes
    tiles = footprint.tiles
    empty = (np.zeros(0, np.int64), np.zeros((0, ev.meta.components(channel), W), np.uint8))
    if bw.rays.size == 0:
        return {t: empty for t in tiles}
    be = get_backend(backend)
    if data is not None:
        cts = data.channel(channel)
    else:
        with _stats.timed("map.read"):
            cts = ev.read_brick(index, channel, backend=be)
    comps = [cts] if data_channel(channel) == "scalar" else cts
    with _stats.timed("map.kernel", int(bw.indptr[-1]) * len(comps)):
        prods = brick_ray_products_multi(comps, bw.indptr, bw.voxels, bw.weights, ev.public_key.nsquare, backend=be)
    return _emit(prods, bw.rays, be, W, camera, tile, tiles, f"brick {index}")


def _emit(prods: list, rays: np.ndarray, be: Any, width: int, camera: Camera, tile: int, tiles: Any,
          what: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """A map task's output: the products of ``rays`` (one batch per component) as records,
    split by image tile (every tile of ``tiles`` present, possibly empty)."""
    t0 = time.perf_counter()
    recs = np.stack([be.to_bytes(p, width) for p in prods], axis=1)  # (R, K, W)
    tid = TileLayout(camera.width, camera.height, tile).ids(rays)
    out = {}
    for t in tiles:
        m = tid == t
        out[t] = (rays[m], recs[m])
    _stats.add("map.emit", time.perf_counter() - t0)
    extra = set(np.unique(tid).tolist()) - set(tiles)
    if extra:  # pragma: no cover - footprint tiles hold every hit pixel of the rectangle
        raise RuntimeError(f"{what}: rays in tiles {sorted(extra)} not planned")
    return out


def map_group(ev: EncryptedVolume, camera: Camera, items: list, sampling: str, step: float, digits: int,
              channel: str, tile: int, backend: str, *data: Any) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """One map task for several resident bricks of one worker, with one output per tile, so
    that the per-task overhead and the merge tasks scale with workers, not bricks.

    Nearest sampling: one product plan over the whole group — a row per ray holding its pairs in
    all the group's bricks (:func:`~hevr.rendering.group_weights.nearest_group_rows`), over the
    concatenation of the bricks' ciphertexts — so each ray's partial sum of the group comes out
    of one multi-exponentiation, and neither per-brick plans nor in-task merges are needed.
    Trilinear: each brick's :func:`map_brick`, then every tile's partials merged here.

    ``items`` lists ``(index, footprint)`` per brick, ``data`` their :class:`ResidentBrick`
    in the same order. The output is the same kind of dict by tile as :func:`map_brick`'s, with
    every tile of any of the bricks' footprints.
    """
    _malloc.tune()
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
        _stats.add("map.geometry", time.perf_counter() - t0, len(items))
        if not rows.rays.size:
            return {t: empty for t in tiles}
        be = get_backend(backend)
        batches = [d.channel(channel) for d in data]
        comps = [be.concat(batches)] if data_channel(channel) == "scalar" else [be.concat([b[c] for b in batches])
                                                                  for c in range(K)]
        with _stats.timed("map.kernel", int(rows.indptr[-1]) * K):
            prods = brick_ray_products_multi(comps, rows.indptr, voxels, rows.weights, n2, backend=be)
        return _emit(prods, rows.rays, be, W, camera, tile, tiles, f"bricks {[idx for idx, _ in items]}")
    parts: dict[int, list] = {}
    for (idx, fp), brick in zip(items, data):
        for t, part in map_brick(ev, camera, idx, sampling, step, digits, channel, fp, tile, backend,
                                 brick).items():
            if part[0].size:
                parts.setdefault(t, []).append(part)
    with _stats.timed("map.merge", len(tiles)):
        return {t: (parts[t][0] if len(parts.get(t, ())) == 1 else
                    merge_partials(parts[t], n2, backend) if t in parts else empty) for t in tiles}


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
    return [keys[i * len(keys) // n:(i + 1) * len(keys) // n] for i in range(n)] if keys else []


def merge_task(nsquare: int, backend: str, tile: int, *parts):
    """One merge task: ⊕ per ray of up to ``FAN_IN`` partial results of tile ``tile``: a map
    task's output (its dict by tile: this tile's entry is taken here, so no selection task
    stands between map and merge) or an earlier merge's ``(rays, records)``."""
    with _stats.timed("merge", 1):
        return merge_partials([p[tile] if isinstance(p, dict) else p for p in parts], nsquare, backend)


def finish_task(plan: RenderPlan, merged: tuple[np.ndarray, np.ndarray], pixels: np.ndarray,
                n_samples: np.ndarray, n: int, width_bytes: int, backend: str = "cpu") -> np.ndarray:
    """One finish task: (P, W) uint8 packed ciphertexts of one tile."""
    with _stats.timed("finish", 1):
        return finish_tile(plan, merged, pixels, n_samples, n, width_bytes, backend)


@dataclass(frozen=True)
class SumsGraph:
    """The merged ray sums of one view as one Dask graph, and its size.

    Attributes
    ----------
    dsk : HighLevelGraph
        Every map, selection and merge task of the view (one layer).
    merged : dict
        Tile id -> key of its merged ``(rays, records)``, or None for a tile no brick touches.
    map_tasks : int
        Bricks whose footprint holds a hit pixel (one map task each, or ``pieces`` map
        tasks in all when split into tile rows).
    edges : int
        (brick, tile) outputs: the sum over bricks of their footprint's tiles. The graph has
        ``pieces <= edges`` map tasks, one selection task per tile that a single brick reaches,
        and per tile of e > 1 partials ``ceil((e - 1)/(FAN_IN - 1))`` merges (the first ones
        take their tile's entry from the map outputs themselves), so at most
        ``edges/(FAN_IN - 1) + tiles`` in all: its size is linear in bricks + tiles + edges.
    pieces : int
        Map tasks: ``map_tasks``, or more when bricks are split into tile rows.
    parts : dict
        Tile id -> the keys of the map tasks holding a partial of it (tiles some brick touches).
        Built with ``fuse=True`` the graph stops there (``merged`` is empty): the reduce blocks
        of :mod:`hevr.rendering.reduce` merge and finish.
    """

    dsk: Any
    layer: str
    merged: dict[int, Any]
    map_tasks: int
    edges: int
    pieces: int
    parts: dict[int, list] = field(default_factory=dict)

    def delayed(self, t: int) -> Any:
        """The merged sums of tile ``t`` as a Dask ``Delayed`` (None if no brick touches it)."""
        key = self.merged.get(t)
        return None if key is None else Delayed(key, self.dsk, layer=self.layer)

    def collection(self) -> Delayed:
        """The graph as a Dask collection, for layers that depend on its map tasks."""
        return Delayed(f"{self.layer}-graph", self.dsk, layer=self.layer)


@dataclass(frozen=True)
class BlockSums:
    """Tile ``tile``'s merged sums inside a reduce block's output ``block`` (a future: they stay
    on the worker that merged them; :mod:`hevr.rendering.reduce`)."""

    block: Any
    tile: int


def block_sums(block: tuple[list, dict], tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The merged sums of ``tile`` in a reduce block's output (inside a finishing task)."""
    return block[1][tile]


def build_sums_graph(ev: EncryptedVolume, camera: Camera, rays: RaySet, sampling: str, step: float, digits: int,
                     channel: str, tile: int, n_tiles: int, backend: str = "cpu",
                     resident: dict | None = None, bands: bool = False,
                     groups: list[list] | None = None, fuse: bool = False) -> SumsGraph:
    """The view's map -> merge graph, built in O(bricks + pixels + edges) on the client.

    Written as a plain task dictionary (Dask's graph specification): a few dictionary
    entries per task, no per-task tokenising. ``resident`` maps brick index -> the brick's
    resident data (a future, or the data itself on a single machine), passed to its map
    task so that the task runs where the brick lives.

    With ``bands`` a brick gets one map task per tile row of its footprint
    (:meth:`Footprint.bands`): the rays, and so the kernel work, are split, not repeated, and
    each (brick, tile) output still comes from one task. Run in image order, the tiles of a row
    then complete as soon as that row's tasks are done and their finishing overlaps the rest of
    the map phase (the tail shrinks from the tiles of the last bricks' footprints to one tile
    row). Only for resident bricks: streamed, each piece would read the brick again.

    With ``groups`` (lists of resident brick indices, one per worker: :func:`resident_groups`)
    each group is one map task (:func:`map_group`), which merges its bricks' partials itself.
    With ``fuse`` the graph holds the map tasks only, and ``parts`` what each tile needs: the
    caller reduces them in blocks (:class:`hevr.rendering.reduce.BlockedReduce`).
    """
    prints = brick_footprints(camera, ev.shape, ev.spacing, ev.brick, rays.n_samples > 0, tile)
    token = dask.base.tokenize(ev.path, ev.meta.store_id, camera.key(), sampling, step, digits, channel, tile,
                               backend, resident is not None, groups is not None)
    leaves: dict[int, list] = {t: [] for t in range(n_tiles)}
    n2 = int(ev.public_key.nsquare)
    dsk: dict[str, Any] = {}
    prio: dict[str, int] = {}
    edges = pieces_total = 0
    for g, group in enumerate(groups or ()):
        items = [(idx, prints[idx]) for idx in group if idx in prints and prints[idx].tiles]  # in view only
        if not items:
            continue
        name = f"hevr-map-{token}-g{g}"
        dsk[name] = (map_group, ev, camera, items, sampling, step, digits, channel, tile, backend,
                     *[resident[idx] for idx, _ in items])
        for t in sorted({t for _, fp in items for t in fp.tiles}):
            leaves[t].append(name)
        pieces_total += 1
        edges += sum(len(fp.tiles) for _, fp in items)
    for idx, fp in (prints.items() if groups is None else ()):
        if not fp.tiles:
            continue
        data = resident.get(idx) if resident is not None else None
        pieces = fp.bands(tile, -(-camera.width // tile)) if bands else [fp]
        for b, piece in enumerate(pieces):
            name = f"hevr-map-{token}-{b}-{idx[0]}-{idx[1]}-{idx[2]}"
            dsk[name] = (map_brick, ev, camera, idx, sampling, step, digits, channel, piece, tile, backend, data)
            prio[name] = -(piece.rect[0] * camera.width + piece.rect[2])
            for t in piece.tiles:
                leaves[t].append(name)
        pieces_total += len(pieces)
        edges += len(fp.tiles)
    merged: dict[int, Any] = {}
    for t, parts in ({} if fuse else leaves).items():
        # A queue of partials: merge the first FAN_IN, put the result at the back. Every merge
        # but the last takes FAN_IN inputs (ceil((e - 1)/(FAN_IN - 1)) merges for e partials)
        # and the rounds stay balanced (depth about log_FAN_IN e).
        if len(parts) == 1:  # one brick reaches this tile: select its entry
            merged[t] = f"hevr-part-{token}-{t}"
            dsk[merged[t]] = (operator.getitem, parts[0], t)
            continue
        queue = deque(parts)
        i = 0
        while len(queue) > 1:
            group = [queue.popleft() for _ in range(min(FAN_IN, len(queue)))]
            key = f"hevr-merge-{token}-{t}-{i}"
            dsk[key] = (merge_task, n2, backend, t, *group)
            queue.append(key)
            i += 1
        merged[t] = queue[0] if queue else None
    layer = f"hevr-sums-{token}"
    hlg = HighLevelGraph({layer: MaterializedLayer(dsk, annotations={"priority": Priorities(prio)})}, {layer: set()})
    return SumsGraph(hlg, layer, merged, len(prints) if groups is None else pieces_total, edges, pieces_total,
                     {t: p for t, p in leaves.items() if p})


@dataclass(frozen=True)
class FinishGraph:
    """The finishing tasks of one view: :func:`~hevr.rendering.finishing.finish_units` per tile.

    Attributes
    ----------
    plan : RenderPlan
    layout : TileLayout
    n_samples : (H*W,) int64
        Samples per pixel (public).
    n : int
        The public modulus.
    backend : str
    units : list of (tile, a, b)
        Every finishing task: pixels ``a:b`` of the tile's pixel list.
    """

    plan: RenderPlan
    layout: TileLayout
    n_samples: np.ndarray
    n: int
    backend: str
    units: list

    @classmethod
    def plan_units(cls, plan: RenderPlan, layout: TileLayout, n_samples: np.ndarray, n: int,
                   backend: str) -> FinishGraph:
        """Cut every tile into finishing units (about one map task's work each)."""
        bits = int(n).bit_length()
        units = [(t, a, b) for t in range(layout.n_tiles)
                 for a, b in finish_units(plan, n_samples[layout.pixels(t)] > 0, bits)]
        return cls(plan, layout, n_samples, int(n), backend, units)

    def tasks(self, merged: dict[int, Any]) -> list[Delayed]:
        """One ``Delayed`` per unit; ``merged`` maps tile -> its merged sums (a ``Delayed``, a
        future, the value itself, or None for a tile no brick touches). A plain task dictionary
        (no per-task tokenising) whose tasks outrank every waiting map task."""
        width = record_width(self.n)
        empty = (np.zeros(0, np.int64), np.zeros((0, 1, width), np.uint8))
        layer = f"hevr-finish-{uuid.uuid4().hex}"
        dsk: dict[str, Any] = {}
        deps = []
        tile_pixels: dict[int, np.ndarray] = {}
        for i, (t, a, b) in enumerate(self.units):
            if t not in tile_pixels:
                tile_pixels[t] = self.layout.pixels(t)
            pix = tile_pixels[t][a:b]
            m = merged.get(t)
            if isinstance(m, Delayed):
                deps.append(m)
                m = m.key
            elif isinstance(m, BlockSums):  # a reduce block's future: select the tile inside the task
                m = (block_sums, m.block, m.tile)
            dsk[f"{layer}-{i}"] = (finish_task, self.plan, m if m is not None else empty, pix, self.n_samples[pix],
                                   self.n, width, self.backend)
        hlg = HighLevelGraph.from_collections(layer, dsk, dependencies=deps)
        hlg.layers[layer].annotations = {"priority": Priorities({})}
        return [Delayed(f"{layer}-{i}", hlg, layer=layer) for i in range(len(self.units))]

    def assemble(self, results: list[np.ndarray]) -> list[np.ndarray]:
        """Each tile's packed ciphertexts: its units' outputs, concatenated in order."""
        per_tile: list[list[np.ndarray]] = [[] for _ in range(self.layout.n_tiles)]
        for (t, _, _), r in zip(self.units, results):
            per_tile[t].append(r)
        return [p[0] if len(p) == 1 else np.concatenate(p) for p in per_tile]
