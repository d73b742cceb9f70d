"""The reduce of a batched render: merge and finish a block of tiles in one task.

When a worker maps all its resident bricks in one task (:func:`~hevr.rendering.pipeline.maps.map_group`),
a frame has G map tasks for G workers, and every tile then has at most G partial sums. The
per-tile graph after them — a selection or a merge task per tile, then a finishing task per
unit — is a few milliseconds of arithmetic spread over ~2 tasks per tile (50 for a 150² frame
in 32² tiles), each paying the scheduler's fixed cost: measured on the 64-bit paper case it is
the frame's tail (0.229 s in 32² tiles against 0.183 s in one tile, ``cuda-host``, 2 workers).

Here the tiles are cut into B runs of raster order (B = G, so the blocks spread over the
workers as the maps do), with about as many finishing units each; one task per block merges
each of its tiles' partials (:func:`~hevr.rendering.pipeline.finishing.merge_partials`) and finishes
every unit of those tiles (:func:`~hevr.rendering.pipeline.finishing.finish_tile`), in the order
:class:`~hevr.rendering.pipeline.graph.FinishGraph` lists them. A second, trivial task per block selects
the units' packed ciphertexts for the client, so the merged sums stay on the worker that made
them (the render cache refers to them by :class:`BlockSums`). So a batched frame is G + 2B
tasks whatever its size, and its packed units — each computed by the same functions from the
same inputs — are byte for byte those of the per-tile graph.
"""

from __future__ import annotations

import itertools
import operator
import uuid
from typing import Any

import numpy as np
from dask.delayed import Delayed
from dask.highlevelgraph import HighLevelGraph
from dask.typing import Key

from ...crypto.records import record_width
from ...runtime import malloc, stats
from ..planning.planner import RenderPlan
from .finishing import finish_tile, merge_partials
from .graph import BlockSums, FinishGraph, Priorities, SumsGraph

__all__ = ["BlockedReduce", "reduce_block"]


def reduce_block(
    plan: RenderPlan, nsquare: int, n: int, backend: str, tiles: list, units: list, *outputs: Any
) -> tuple[list[np.ndarray], dict]:
    """One reduce task: ``(packed units, {tile: merged sums})`` of a block of tiles.

    ``tiles`` lists ``(tile, [indices into outputs])`` — the map outputs (dicts by tile) that
    hold a partial of the tile, none for a tile no brick touches; ``units`` lists ``(tile,
    pixels, n_samples)`` per finishing unit, in order.
    """
    malloc.tune()
    width = record_width(n)
    with stats.timed("merge", len(tiles)):
        merged = {
            t: (outputs[idx[0]][t] if len(idx) == 1 else merge_partials([outputs[i][t] for i in idx], nsquare, backend))
            for t, idx in tiles
            if idx
        }
    empty = (np.zeros(0, np.int64), np.zeros((0, 1, width), np.uint8))
    with stats.timed("finish", len(units)):
        packed = [finish_tile(plan, merged.get(t, empty), pix, ns, n, width, backend) for t, pix, ns in units]
    return packed, merged


class BlockedReduce:
    """The reduce blocks of one batched render (module docstring).

    Parameters
    ----------
    graph : SumsGraph
        The map tasks, built with ``fuse=True`` (its ``parts`` list each tile's map outputs).
    finish : FinishGraph
        The finishing units, whose order the blocks keep.
    n_blocks : int
        B, the number of blocks (at most one per tile).
    """

    def __init__(self, graph: SumsGraph, finish: FinishGraph, n_blocks: int) -> None:
        self.graph, self.finish = graph, finish
        units = finish.units
        n_tiles = finish.layout.n_tiles
        B = max(1, min(int(n_blocks), n_tiles))
        # cut at tile boundaries, about len(units)/B units each
        per_tile = np.bincount([t for t, _, _ in units], minlength=n_tiles)
        ends = np.searchsorted(np.cumsum(per_tile), [len(units) * (b + 1) / B for b in range(B)], side="left") + 1
        bounds = [0, *sorted(set(np.minimum(ends, n_tiles).tolist()))]
        self.tiles = [list(range(a, b)) for a, b in itertools.pairwise(bounds) if b > a]
        if bounds[-1] < n_tiles:  # pragma: no cover - the last end is n_tiles
            self.tiles.append(list(range(bounds[-1], n_tiles)))
        block_of = np.zeros(n_tiles, np.int64)
        for b, block in enumerate(self.tiles):
            block_of[block] = b
        mine: list[list] = [[] for _ in self.tiles]  # each block's units, in order: one pass over the units
        tile_pixels: dict[int, np.ndarray] = {}
        for t, a, z in units:
            if t not in tile_pixels:
                tile_pixels[t] = finish.layout.pixels(t)
            pix = tile_pixels[t][a:z]
            mine[block_of[t]].append((t, pix, finish.n_samples[pix]))
        self.starts = np.cumsum([0, *(len(m) for m in mine[:-1])]).tolist()  # the first unit of each block
        self.layer = f"hevr-reduce-{uuid.uuid4().hex}"  # the finishing plan is in the task: a key per render
        dsk: dict[Key, Any] = {}
        for b, block in enumerate(self.tiles):
            inputs = sorted({k for t in block for k in graph.parts.get(t, ())})
            pos = {k: i for i, k in enumerate(inputs)}
            spec = [(t, [pos[k] for k in graph.parts.get(t, ())]) for t in block]
            n = finish.n
            dsk[self.key(b)] = (reduce_block, finish.plan, n * n, n, finish.backend, spec, mine[b], *inputs)
            dsk[f"{self.layer}-units-{b}"] = (operator.getitem, self.key(b), 0)
        # dask's Delayed does not match its own DaskCollection protocol (__dask_scheduler__ is no staticmethod)
        deps = [graph.collection()]
        hlg = HighLevelGraph.from_collections(self.layer, dsk, dependencies=deps)  # type: ignore[arg-type]
        hlg.layers[self.layer].annotations = {"priority": Priorities({})}
        self.hlg = hlg

    def key(self, b: int) -> str:
        return f"{self.layer}-{b}"

    def unit_tasks(self) -> list[Delayed]:
        """One ``Delayed`` per block: the packed ciphertexts of its units (a list, in order)."""
        return [Delayed(f"{self.layer}-units-{b}", self.hlg, layer=self.layer) for b in range(len(self.tiles))]

    def block_tasks(self) -> list[Delayed]:
        """One ``Delayed`` per block: its whole output (units and merged sums), to keep."""
        return [Delayed(self.key(b), self.hlg, layer=self.layer) for b in range(len(self.tiles))]

    def on_block(self, on_unit: Any) -> Any:
        """An ``on_result`` for :func:`hevr.runtime.scheduler.compute` over :meth:`unit_tasks` that hands
        each unit to ``on_unit(i, packed)`` under its index among all units (None: None)."""
        if on_unit is None:
            return None

        def call(b: int, packed: list) -> None:
            for j, p in enumerate(packed):
                on_unit(self.starts[b] + j, p)

        return call

    def units(self, results: list[list]) -> list[np.ndarray]:
        """Every unit's packed ciphertexts, in :class:`FinishGraph` order, from the blocks' lists."""
        return [p for packed in results for p in packed]

    def sums(self, blocks: list, client: Any) -> dict:
        """Tile -> its merged sums for the render cache: a :class:`BlockSums` of the block's
        future on a distributed client, else the value itself; None for a tile no brick touches."""
        out: dict = {}
        for block, value in zip(self.tiles, blocks):
            for t in block:
                if not self.graph.parts.get(t):
                    out[t] = None
                elif client is not None:
                    out[t] = BlockSums(value, t)
                else:
                    out[t] = value[1][t]
        return out
