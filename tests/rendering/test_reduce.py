"""The reduce of a batched render (hevr.rendering.pipeline.reduce): G map tasks, then B blocks that merge
and finish their tiles — the same packed ciphertexts as the per-tile graph of per-brick maps, and
the same cached sums for re-colouring, saved sums, deferred renders and streamed frames."""

from __future__ import annotations

import dask
import numpy as np
import pytest
from distributed import get_task_stream

import hevr
from hevr.image.tiles import TileLayout
from hevr.rendering.encrypted import error_bound
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.pipeline import cache as render_cache
from hevr.rendering.pipeline.graph import BlockSums, FinishGraph, build_sums_graph
from hevr.rendering.pipeline.reduce import BlockedReduce, reduce_block
from hevr.rendering.planning.modes import make_spec
from hevr.rendering.planning.planner import plan_render

SHAPE, BRICK, SPACING, K = (7, 9, 11), (3, 4, 5), (1.0, 0.8, 1.3), 4
NODES = [(0.279, "blue"), (0.797, "red")]
OTHER = [(0.3, "green"), (0.7, "#ff00ff")]
PER_BRICK = {"hevr.render.resident-batch": False}


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(23).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    return hevr.encrypt_volume(
        volume,
        tmp_path_factory.mktemp("reduce") / "v.zarr",
        keypair256[1],
        brick=BRICK,
        spacing=SPACING,
        vector_dims=K,
        progress=False,
    )


@pytest.fixture(scope="module")
def camera(store):
    return hevr.Camera.orbit(store, azimuth=35, elevation=25, width=13, height=10)


def _same(a, b) -> bool:
    return len(a.ciphertexts) == len(b.ciphertexts) and all(
        np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts)
    )


def _plain(ev, volume, cam, mode, sampling, kw):
    return hevr.render_plain(
        volume, cam, mode=mode, sampling=sampling, spacing=SPACING, vector_dims=K, **kw
    ), error_bound(ev, cam, mode, sampling, **kw)


@pytest.mark.parametrize(
    "mode,sampling,kw,finish",
    [
        ("xray", "nearest", {}, "client"),
        ("xray", "trilinear", {}, "server"),
        ("tf", "nearest", {"nodes": NODES}, "client"),
        ("tf", "trilinear", {"nodes": NODES}, "server"),
    ],
)
def test_blocks_give_the_per_tile_graph_s_image_in_few_tasks(
    store, volume, keypair256, camera, cluster, mode, sampling, kw, finish
):
    with cluster.as_current():
        ev2 = store.persist()
        ev2.resident.wait()
        with get_task_stream(client=cluster) as ts:
            batched = hevr.render(ev2, camera, mode, sampling, progress=False, cache=False, tile=4, finish=finish, **kw)
        with dask.config.set(PER_BRICK):
            per_tile = hevr.render(
                ev2, camera, mode, sampling, progress=False, cache=False, tile=4, finish=finish, **kw
            )
    keys = [str(t["key"]) for t in ts.data]
    maps = [k for k in keys if k.startswith("hevr-map-")]
    assert not any(k.startswith(("hevr-merge-", "hevr-part-", "hevr-finish-")) for k in keys)
    assert 1 <= len(maps) <= 2 and len(keys) == len(maps) + 2 * batched.stats["finish_tasks"]
    assert 1 <= batched.stats["finish_tasks"] <= 2 < per_tile.stats["finish_tasks"]  # 13x10 in 4² tiles: 12
    assert _same(batched, per_tile)
    ref, bound = _plain(store, volume, camera, mode, sampling, kw)
    assert np.all(np.abs(batched.decrypt(keypair256[1]) - ref) <= bound) and np.count_nonzero(ref) > 10


def test_cached_block_sums_recolour_save_and_stream(store, volume, keypair256, camera, cluster, tmp_path):
    """The cache refers to a block's merged sums by BlockSums (they stay on the worker); a
    server-finished re-colouring, saved sums and a streamed frame all come from them."""
    priv = keypair256[1]
    hevr.clear_cache()
    with cluster.as_current():
        ev2 = store.persist()
        ev2.resident.wait()
        first = hevr.render(
            ev2,
            camera,
            "tf",
            "nearest",
            nodes=NODES,
            progress=False,
            finish="server",
            tile=4,
            keep_sums=tmp_path / "s.hevrsums",
        )
        sums = next(iter(render_cache._CACHE.values()))
        assert any(isinstance(v, BlockSums) for v in sums.tiles.values())
        with get_task_stream(client=cluster) as ts:
            again = hevr.render(ev2, camera, "tf", "nearest", nodes=OTHER, progress=False, finish="server", tile=4)
        assert again.stats["reused_ray_sums"] and not any(str(t["key"]).startswith("hevr-map-") for t in ts.data)
        frame = hevr.render_frame(ev2, camera, priv, "tf", "nearest", nodes=NODES, progress=False, cache=False, tile=4)
        deferred = hevr.render(
            ev2,
            camera,
            "tf",
            "nearest",
            nodes=OTHER,
            progress=False,
            finish="server",
            tile=4,
            cache=False,
            compute=False,
        ).compute()
    with dask.config.set(PER_BRICK):
        ref_other = hevr.render(
            store, camera, "tf", "nearest", nodes=OTHER, progress=False, finish="server", tile=4, cache=False
        )
    assert _same(again, ref_other) and _same(deferred, ref_other)
    recoloured = hevr.recolour(tmp_path / "s.hevrsums", "tf", nodes=OTHER, finish="server", progress=False)
    assert _same(recoloured, ref_other)
    ref, bound = _plain(store, volume, camera, "tf", "nearest", {"nodes": NODES})
    assert np.all(np.abs(frame.image - ref) <= bound) and np.all(np.abs(first.decrypt(priv) - ref) <= bound)


def test_blocks_cut_tiles_in_raster_runs_keeping_unit_order(store, camera):
    """B runs of whole tiles with about as many units each; the blocks' units in block order are
    FinishGraph's units in order; a block of a tile no brick touches finishes it empty."""
    rays = cast_rays(camera, store.shape, store.spacing, 1.0)
    spec = make_spec("xray", "nearest", 1.0, None, None, K, True, False, False)
    plan = plan_render(
        n=int(store.public_key.n),
        spec=spec,
        meta=store.meta,
        n_samples=rays.n_samples,
        digits=0,
        precision=4,
        comb_digits=4,
        pack=True,
        combination=None,
        finish="client",
    )
    layout = TileLayout(camera.width, camera.height, 4)
    finish = FinishGraph.plan_units(plan, layout, rays.n_samples, int(store.public_key.n), "cpu")
    graph = build_sums_graph(
        store,
        camera,
        rays,
        "nearest",
        1.0,
        0,
        "scalar",
        4,
        layout.n_tiles,
        "cpu",
        resident={idx: None for idx in store.brick_indices()},
        groups=[store.brick_indices()],
        fuse=True,
    )
    assert graph.merged == {} and graph.parts
    for B in (1, 2, 3, 5, 100):
        red = BlockedReduce(graph, finish, B)
        tiles = [t for block in red.tiles for t in block]
        assert tiles == list(range(layout.n_tiles)) and len(red.tiles) == min(B, layout.n_tiles)
        counts = [sum(1 for t, _, _ in finish.units if t in block) for block in red.tiles]
        assert red.starts == np.cumsum([0, *counts[:-1]]).tolist()  # each block's first unit
        got = [(t, pix.tolist()) for b in range(len(red.tiles)) for t, pix, _ in red.hlg[red.key(b)][6]]
        want = [(t, layout.pixels(t)[a:z].tolist()) for t, a, z in finish.units]
        assert got == want  # the blocks' units, in block order, are FinishGraph's
        assert max(counts) - min(counts) <= 2 * max(np.bincount([t for t, _, _ in finish.units]))
    n = int(store.public_key.n)
    pix = layout.pixels(0)
    packed, merged = reduce_block(plan, n * n, n, "cpu", [(0, [])], [(0, pix, np.zeros(pix.size, np.int64))])
    assert merged == {} and packed[0].shape[0] == 0  # no hit pixel: nothing to pack
