"""The Dask graph: distributed vs default scheduler, tree reduce, worker loss, corrupt bricks."""

from __future__ import annotations

import os
import signal
import threading
import time

import dask
import numpy as np
import pytest
from distributed import Client, LocalCluster

import hevr
from hevr.rendering.encrypted import error_bound
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.pipeline.graph import FAN_IN, build_sums_graph

SHAPE = (7, 9, 11)
BRICK = (3, 4, 5)
MODES = [("xray", {}), ("emphasize", {"density": 0.653}), ("tf", {"nodes": [(0.279, "blue"), (0.797, "red")]})]


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(9).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    return hevr.encrypt_volume(
        volume, tmp_path_factory.mktemp("mr") / "v.zarr", keypair256[1], brick=BRICK, vector_dims=4, progress=False
    )


@pytest.fixture(scope="module")
def client():
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as c,
    ):
        yield c


@pytest.mark.slow
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode, kw", MODES, ids=[m for m, _ in MODES])
def test_distributed_equals_default_scheduler(store, volume, keypair256, client, mode, kw, sampling):
    _, priv = keypair256
    cam = hevr.Camera.orbit(store, azimuth=25, elevation=15, width=12, height=10)
    a = hevr.render(store, cam, mode=mode, sampling=sampling, cache=False, client=client, progress=False, **kw)
    with dask.config.set(scheduler="sync"):
        b = hevr.render(store, cam, mode=mode, sampling=sampling, cache=False, progress=False, **kw)
    assert all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts))
    got = a.decrypt(priv)
    assert np.array_equal(got, b.decrypt(priv))
    ref = hevr.render_plain(volume, cam, mode=mode, sampling=sampling, vector_dims=4, **kw)
    assert np.all(np.abs(got - ref) <= error_bound(store, cam, mode, sampling, **kw))


def test_active_client_is_used(store, client):
    cam = hevr.Camera.orbit(store, width=8, height=8)
    from distributed import get_task_stream

    with client.as_current(), get_task_stream(client=client) as ts:
        hevr.render(store, cam, cache=False, progress=False)
    names = [t["key"] for t in ts.data]
    assert any("hevr-map" in str(k) for k in names) and any("hevr-finish" in str(k) for k in names)


def test_tree_reduce_no_task_receives_every_partial(store):
    cam = hevr.Camera.orbit(store, azimuth=25, elevation=15, width=40, height=40)
    rays = cast_rays(cam, store.shape, store.spacing, 1.0)
    g = build_sums_graph(store, cam, rays, "trilinear", 1.0, 3, "scalar", tile=8, n_tiles=25)
    n_map = g.map_tasks
    assert n_map > 1
    graph = dict(g.dsk)
    for key in graph:
        deps = dask.core.get_dependencies(graph, key)
        if str(key).startswith("hevr-merge"):
            assert len(deps) <= FAN_IN
    maps = [k for k in graph if str(k).startswith("hevr-map")]
    assert len(maps) == n_map
    for key in graph:
        if str(key).startswith("hevr-merge"):
            assert len(dask.core.get_dependencies(graph, key)) < len(maps)


def test_untouched_bricks_cost_nothing(store):
    nz, ny, nx = store.shape
    centre = ((nx - 1) / 2, (ny - 1) / 2, (nz - 1) / 2)
    # a thin parallel beam through the first brick column only
    cam = hevr.Camera(
        position=(1.0, 1.0, 50.0), focal_point=(1.0, 1.0, 0.0), width=2, height=2, parallel=True, parallel_scale=0.5
    )
    rays = cast_rays(cam, store.shape, store.spacing, 1.0)
    g = build_sums_graph(store, cam, rays, "nearest", 1.0, 0, "scalar", tile=32, n_tiles=1)
    n_map = g.map_tasks
    assert n_map == store.grid[0]  # one brick per z-layer, nothing else
    assert centre  # documented for readers: the beam avoids the centre bricks


@pytest.mark.slow
def test_render_survives_a_killed_worker(tmp_path, keypair512):
    pub, priv = keypair512
    vol = np.random.default_rng(4).integers(0, 256, (12, 12, 12)).astype(np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", priv, brick=4, vector_dims=4, progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=48, height=48)
    nodes = [(0.2, "blue"), (0.8, "red")]
    with (
        dask.config.set({"distributed.scheduler.allowed-failures": 10}),
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as c,
    ):
        reference = hevr.render(
            ev, cam, mode="tf", nodes=nodes, sampling="trilinear", cache=False, client=c, progress=False
        )
        pids = c.run(os.getpid)
        result = {}

        def run():
            result["img"] = hevr.render(
                ev, cam, mode="tf", nodes=nodes, sampling="trilinear", cache=False, client=c, progress=False
            )

        th = threading.Thread(target=run)
        th.start()
        deadline = time.time() + 30
        victim = None
        while time.time() < deadline and victim is None:
            processing = c.processing()
            busy = [w for w, tasks in processing.items() if any("hevr-map" in str(t) for t in tasks)]
            if busy:
                victim = busy[0]
            time.sleep(0.02)
        assert victim is not None, "no map task was seen running"
        os.kill(pids[victim], signal.SIGKILL)
        th.join(timeout=180)
        assert not th.is_alive()
    assert np.array_equal(result["img"].decrypt(priv), reference.decrypt(priv))


def test_corrupt_brick_aborts_render_naming_it(tmp_path, keypair256, volume):
    ev = hevr.encrypt_volume(volume, tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
    chunk = tmp_path / "v.zarr" / "scalar" / "c" / "1" / "1" / "1" / "0"
    chunk.write_bytes(b"\xff" * len(chunk.read_bytes()))
    cam = hevr.Camera.orbit(ev, width=10, height=10)
    with dask.config.set(scheduler="sync"), pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 1\)"):
        hevr.render(hevr.open_volume(tmp_path / "v.zarr"), cam, cache=False, progress=False)
