"""The MapReduce render graph on Dask (after Stuart et al.).

map     one task per brick whose footprint (:mod:`hevr.rendering.geometry.footprint`) holds a hit
        pixel: cast the footprint's rays, compute the brick's plaintext weights, read the
        brick inside the task (or take it from worker memory when the volume is resident),
        run the encrypted kernel, and emit partial ray sums split by image tile, as compact
        bytes (ray ids + fixed-width ciphertext records).
reduce  per image tile, a tree of merges (fan-in 4) multiplies the partials of the same
        ray (fpAdd of partial sums that share one exponent); no task receives every partial.
finish  per tile: per-pixel combination, reciprocal normalisation, offset and packing.

The map tasks themselves are :mod:`hevr.rendering.pipeline.maps`. Resident bricks below 1024-bit keys, and
on a GPU at any key size, are mapped one task per worker (:func:`~hevr.rendering.pipeline.maps.map_group`);
every tile then has at most one partial per worker, and merge and finish run in one task per block
of tiles instead (:mod:`hevr.rendering.pipeline.reduce`).

The graph holds public data only (the volume handle, camera, plan) and the *name* of the
arithmetic backend; every task resolves the backend in its own process
(:func:`hevr.backends.get_backend`), and converts bytes to the backend's form once.
"""

from __future__ import annotations

import logging
import operator
import uuid
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import dask
import numpy as np
from dask.delayed import Delayed
from dask.highlevelgraph import HighLevelGraph, MaterializedLayer
from dask.typing import Key

from ...crypto.records import record_width
from ...image.tiles import TileLayout
from ...runtime import stats
from ...store.reader import EncryptedVolume
from ..geometry.camera import Camera
from ..geometry.footprint import brick_footprints
from ..geometry.plane import Plane
from ..geometry.rays import RaySet
from ..planning.planner import RenderPlan
from .finishing import finish_tile, finish_units, merge_partials
from .maps import map_brick, map_group

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


def merge_task(nsquare: int, backend: str, tile: int, *parts):
    """One merge task: ⊕ per ray of up to ``FAN_IN`` partial results of tile ``tile``: a map
    task's output (its dict by tile: this tile's entry is taken here, so no selection task
    stands between map and merge) or an earlier merge's ``(rays, records)``."""
    with stats.timed("merge", 1):
        return merge_partials([p[tile] if isinstance(p, dict) else p for p in parts], nsquare, backend)


def finish_task(
    plan: RenderPlan,
    merged: tuple[np.ndarray, np.ndarray],
    pixels: np.ndarray,
    n_samples: np.ndarray,
    n: int,
    width_bytes: int,
    backend: str = "cpu",
) -> np.ndarray:
    """One finish task: (P, W) uint8 packed ciphertexts of one tile."""
    with stats.timed("finish", 1):
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
        of :mod:`hevr.rendering.pipeline.reduce` merge and finish.
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
    on the worker that merged them; :mod:`hevr.rendering.pipeline.reduce`)."""

    block: Any
    tile: int


def block_sums(block: tuple[list, dict], tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The merged sums of ``tile`` in a reduce block's output (inside a finishing task)."""
    return block[1][tile]


def build_sums_graph(
    ev: EncryptedVolume,
    camera: Camera | Plane,
    rays: RaySet,
    sampling: str,
    step: float,
    digits: int,
    channel: str,
    tile: int,
    n_tiles: int,
    backend: str = "cpu",
    resident: dict | None = None,
    bands: bool = False,
    groups: list[list] | None = None,
    fuse: bool = False,
) -> SumsGraph:
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
    caller reduces them in blocks (:class:`hevr.rendering.pipeline.reduce.BlockedReduce`).
    """
    prints = brick_footprints(camera, ev.shape, ev.spacing, ev.brick, rays.n_samples > 0, tile)
    token = dask.base.tokenize(
        ev.path,
        ev.meta.store_id,
        camera.key(),
        sampling,
        step,
        digits,
        channel,
        tile,
        backend,
        resident is not None,
        groups is not None,
    )
    leaves: dict[int, list] = {t: [] for t in range(n_tiles)}
    n2 = int(ev.public_key.nsquare)
    dsk: dict[str, Any] = {}
    prio: dict[str, int] = {}
    edges = pieces_total = 0
    for g, group in enumerate(groups or ()):
        assert resident is not None  # groups are of resident bricks (resident_groups)
        items = [(idx, prints[idx]) for idx in group if idx in prints and prints[idx].tiles]  # in view only
        if not items:
            continue
        name = f"hevr-map-{token}-g{g}"
        dsk[name] = (
            map_group,
            ev,
            camera,
            items,
            sampling,
            step,
            digits,
            channel,
            tile,
            backend,
            *[resident[idx] for idx, _ in items],
        )
        for t in sorted({t for _, fp in items for t in fp.tiles}):
            leaves[t].append(name)
        pieces_total += 1
        edges += sum(len(fp.tiles) for _, fp in items)
    for idx, fp in prints.items() if groups is None else ():
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
    return SumsGraph(
        hlg,
        layer,
        merged,
        len(prints) if groups is None else pieces_total,
        edges,
        pieces_total,
        {t: p for t, p in leaves.items() if p},
    )


@dataclass(frozen=True)
class FinishGraph:
    """The finishing tasks of one view: :func:`~hevr.rendering.pipeline.finishing.finish_units` per tile.

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
    def plan_units(
        cls, plan: RenderPlan, layout: TileLayout, n_samples: np.ndarray, n: int, backend: str
    ) -> FinishGraph:
        """Cut every tile into finishing units (about one map task's work each)."""
        bits = int(n).bit_length()
        units = [
            (t, a, b)
            for t in range(layout.n_tiles)
            for a, b in finish_units(plan, n_samples[layout.pixels(t)] > 0, bits)
        ]
        return cls(plan, layout, n_samples, int(n), backend, units)

    def tasks(self, merged: dict[int, Any]) -> list[Delayed]:
        """One ``Delayed`` per unit; ``merged`` maps tile -> its merged sums (a ``Delayed``, a
        future, the value itself, or None for a tile no brick touches). A plain task dictionary
        (no per-task tokenising) whose tasks outrank every waiting map task."""
        width = record_width(self.n)
        empty = (np.zeros(0, np.int64), np.zeros((0, 1, width), np.uint8))
        layer = f"hevr-finish-{uuid.uuid4().hex}"
        dsk: dict[Key, Any] = {}
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
            dsk[f"{layer}-{i}"] = (
                finish_task,
                self.plan,
                m if m is not None else empty,
                pix,
                self.n_samples[pix],
                self.n,
                width,
                self.backend,
            )
        # dask's Delayed does not match its own DaskCollection protocol (__dask_scheduler__ is no staticmethod)
        hlg = HighLevelGraph.from_collections(layer, dsk, dependencies=deps)  # type: ignore[arg-type]
        hlg.layers[layer].annotations = {"priority": Priorities({})}
        return [Delayed(f"{layer}-{i}", hlg, layer=layer) for i in range(len(self.units))]

    def assemble(self, results: list[np.ndarray]) -> list[np.ndarray]:
        """Each tile's packed ciphertexts: its units' outputs, concatenated in order."""
        per_tile: list[list[np.ndarray]] = [[] for _ in range(self.layout.n_tiles)]
        for (t, _, _), r in zip(self.units, results):
            per_tile[t].append(r)
        return [p[0] if len(p) == 1 else np.concatenate(p) for p in per_tile]
