"""Resident volumes: EncryptedVolume.persist keeps decoded bricks in memory across renders."""

from __future__ import annotations

import logging
import os
import pickle
import signal
import time

import dask
import gmpy2
import numpy as np
import pytest
from distributed import Client, LocalCluster, get_task_stream

import hevr
from hevr.rendering import view as view_mod
from hevr.rendering.encrypted import error_bound
from hevr.store import reader as reader_mod
from hevr.store import resident as resident_mod
from hevr.store.resident import (
    RESIDENT_MEMORY_KEY,
    Residency,
    ResidentBrick,
    residue_bytes,
)

SHAPE = (7, 9, 11)
BRICK = (3, 4, 5)  # 27 bricks, edge bricks smaller
SPACING = (1.0, 0.8, 1.3)
K = 4
NODES = [(0.279, "blue"), (0.797, "red")]
RENDERS = [
    ("xray", "nearest", {}),
    ("xray", "trilinear", {}),
    ("tf", "nearest", {"nodes": NODES}),
    ("tf", "trilinear", {"nodes": NODES}),
]
IDS = [f"{m}-{s}" for m, s, _ in RENDERS]


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(17).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    return hevr.encrypt_volume(
        volume,
        tmp_path_factory.mktemp("resident") / "v.zarr",
        keypair256[1],
        brick=BRICK,
        spacing=SPACING,
        vector_dims=K,
        progress=False,
    )


@pytest.fixture(scope="module")
def camera(store):
    return hevr.Camera.orbit(store, azimuth=35, elevation=25, width=13, height=10)


def _render(ev, cam, mode, sampling, kw, **extra):
    return hevr.render(ev, cam, mode=mode, sampling=sampling, cache=False, progress=False, **extra, **kw)


def _same(a, b) -> bool:
    return len(a.ciphertexts) == len(b.ciphertexts) and all(
        np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts)
    )


def _check_plain(img, ev, volume, cam, mode, sampling, kw, priv):
    got = img.decrypt(priv)
    ref = hevr.render_plain(volume, cam, mode=mode, sampling=sampling, spacing=SPACING, vector_dims=K, **kw)
    assert np.all(np.abs(got - ref) <= error_bound(ev, cam, mode, sampling, **kw))
    assert np.count_nonzero(ref) > 10
    return got


def _voxels() -> int:
    return int(np.prod(SHAPE))


def _clean_residue_bytes(width: int) -> int:
    """residue_bytes after churning gmpy2's free-object cache: it must not matter (the size is a
    formula of the width, see test_residue_bytes_depends_only_on_the_width)."""
    small = [gmpy2.mpz(i) for i in range(1000)]
    del small
    return residue_bytes(width)


def _check_brick_sizes(bricks) -> None:
    for b in bricks:
        n_cts = sum(len(v) if ch == "scalar" else sum(len(x) for x in v) for ch, v in b.batches.items())
        assert n_cts > 0 and b.nbytes % n_cts == 0 and b.nbytes // n_cts > 8 + 64  # an mpz of a 64-byte record


# -- single machine ------------------------------------------------------------------------------------


def test_persist_without_client_holds_every_brick(store):
    ev = hevr.open_volume(store.path)
    per_ct = _clean_residue_bytes(store.meta.ciphertext_bytes)
    ev2 = ev.persist()
    assert ev2 is not ev and ev.resident is None  # the original handle keeps streaming
    res = ev2.resident
    assert isinstance(res, Residency) and res.client is None and res.backend == "cpu"
    assert res.channels == ("scalar", "vector")
    assert sorted(res.bricks) == sorted(store.brick_indices()) and len(res.bricks) == 27
    assert list(res.worker_bytes) == ["local"] and res.worker_bytes["local"] == res.nbytes
    assert res.nbytes == _voxels() * (1 + K) * per_ct and per_ct > store.meta.ciphertext_bytes
    res.wait()  # nothing to wait for on a single machine
    for idx, brick in res.bricks.items():
        assert isinstance(brick, ResidentBrick) and brick.index == idx
        assert brick.channel("scalar") == store.read_brick(idx, "scalar")
        assert brick.channel("vector") == store.read_brick(idx, "vector")
        assert len(brick.channel("vector")) == K and len(brick.channel("scalar")) == np.prod(store.brick_shape(idx))
        assert brick.__sizeof__() == brick.nbytes > 0
    _check_brick_sizes(res.bricks.values())
    assert "resident=scalar+vector" in repr(ev2) and "resident=" not in repr(ev)


@pytest.mark.parametrize("mode, sampling, kw", RENDERS, ids=IDS)
def test_resident_equals_streamed_default_scheduler(store, volume, keypair256, camera, mode, sampling, kw):
    ev2 = store.persist()
    a = _render(ev2, camera, mode, sampling, kw)
    b = _render(store, camera, mode, sampling, kw)
    assert a.stats["resident"] is True and b.stats["resident"] is False
    assert _same(a, b)
    got = _check_plain(a, store, volume, camera, mode, sampling, kw, keypair256[1])
    assert np.array_equal(got, b.decrypt(keypair256[1]))


def test_resident_render_reads_no_brick(store, camera, monkeypatch):
    """Every map task takes its brick from memory: the store is not read during the render."""
    ev2 = store.persist()
    reads = []
    original = reader_mod.EncryptedVolume.read_brick_bytes
    monkeypatch.setattr(
        reader_mod.EncryptedVolume, "read_brick_bytes", lambda self, *a, **k: reads.append(a) or original(self, *a, **k)
    )
    with dask.config.set(scheduler="sync"):
        img = _render(ev2, camera, "tf", "trilinear", {"nodes": NODES})
        assert img.stats["resident"] and reads == []
        streamed = _render(store, camera, "tf", "trilinear", {"nodes": NODES})
    assert 0 < len(reads) <= streamed.stats["map_tasks"]  # the streamed render reads its bricks
    # resident: one map task per group of bricks (one per thread here), not one per brick
    assert img.stats["map_tasks"] <= min(dask.system.CPU_COUNT, streamed.stats["map_tasks"])


def test_scalar_resident_tf_render_streams(store, volume, keypair256, camera, caplog):
    ev2 = store.persist(channels="scalar")
    assert ev2.resident.channels == ("scalar",)
    assert ev2.resident.nbytes * (1 + K) == store.persist().resident.nbytes  # a fifth of the ciphertexts
    with caplog.at_level(logging.WARNING, logger="hevr.rendering.view"):
        tf = _render(ev2, camera, "tf", "trilinear", {"nodes": NODES})
    assert tf.stats["resident"] is False and "streaming from the store" in caplog.text
    _check_plain(tf, store, volume, camera, "tf", "trilinear", {"nodes": NODES}, keypair256[1])
    assert _same(tf, _render(store, camera, "tf", "trilinear", {"nodes": NODES}))
    xray = _render(ev2, camera, "xray", "nearest", {})
    assert xray.stats["resident"] is True
    _check_plain(xray, store, volume, camera, "xray", "nearest", {}, keypair256[1])


def test_pickled_handle_carries_no_bricks(store, camera):
    ev2 = store.persist()
    blob = pickle.dumps(ev2)
    assert len(blob) == len(pickle.dumps(hevr.open_volume(store.path))) < 4096
    assert ev2.resident.nbytes > 100 * len(blob)
    back = pickle.loads(blob)
    assert back.resident is None and back.path == store.path and back.meta == store.meta
    assert ev2.resident is not None and len(ev2.resident.bricks) == 27  # pickling did not strip the original
    assert _render(back, camera, "xray", "nearest", {}).stats["resident"] is False


@pytest.mark.parametrize("channels", ["nonsense", ["scalar", "nonsense"], [], "Scalar", ("scalar", None)])
def test_bad_channels(store, channels):
    with pytest.raises(hevr.ParameterError, match="channels"):
        store.persist(channels=channels)


def test_non_sequence_channels(store):
    with pytest.raises(hevr.ParameterError, match="channels"):
        store.persist(channels=3)


def test_missing_channel(tmp_path, keypair256):
    ev = hevr.encrypt_volume(np.ones((4, 4, 4), np.uint8), tmp_path / "s.zarr", keypair256[1], brick=2, progress=False)
    with pytest.raises(hevr.ParameterError, match="channels"):
        ev.persist(channels="vector")
    assert ev.persist(channels=["scalar", "scalar"]).resident.channels == ("scalar",)


def test_bad_backend(store):
    with pytest.raises(hevr.HevrError):
        store.persist(backend="no-such-backend")


def test_memory_limit_refuses_before_loading(store, monkeypatch):
    def forbidden(*a, **k):
        raise AssertionError("a brick was loaded")

    monkeypatch.setattr(resident_mod, "load_brick", forbidden)
    with dask.config.set({RESIDENT_MEMORY_KEY: 1e-9}):
        with pytest.raises(hevr.MemoryLimitError, match="hevr.limits.resident-memory") as info:
            store.persist()
    assert isinstance(info.value, MemoryError) and isinstance(info.value, hevr.HevrError)
    assert "worker local" in str(info.value)
    with dask.config.set({RESIDENT_MEMORY_KEY: 1e-9}), pytest.raises(hevr.MemoryLimitError):
        store.persist(channels="scalar")


@pytest.mark.parametrize("value", [2, "x", 0, -0.5, float("nan"), None, [0.5]])
def test_memory_limit_must_be_a_fraction(store, value, monkeypatch):
    monkeypatch.setattr(resident_mod, "load_brick", lambda *a, **k: pytest.fail("a brick was loaded"))
    with (
        dask.config.set({RESIDENT_MEMORY_KEY: value}),
        pytest.raises(hevr.ParameterError, match="hevr.limits.resident-memory"),
    ):
        store.persist()


@pytest.mark.parametrize("value", [1, 1.0, "0.75", 0.5])
def test_memory_limit_accepts_fractions(store, value):
    with dask.config.set({RESIDENT_MEMORY_KEY: value}):
        assert len(store.persist(channels="scalar").resident.bricks) == 27


def _corrupt(path, idx=(1, 1, 1)):
    chunk = path / "scalar" / "c" / "/".join(map(str, idx)) / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x40
    chunk.write_bytes(bytes(data))


def test_corrupt_chunk_fails_loading_the_resident_brick(tmp_path, keypair256, volume, camera):
    hevr.encrypt_volume(volume, tmp_path / "v.zarr", keypair256[1], brick=BRICK, spacing=SPACING, progress=False)
    _corrupt(tmp_path / "v.zarr")
    ev = hevr.open_volume(tmp_path / "v.zarr")  # a flipped byte keeps the chunk's size: quick open passes
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 1\)"):
        hevr.render(ev.persist(), camera, progress=False, cache=False)


def test_release_drops_the_bricks(store, volume, keypair256, camera):
    ev2 = store.persist()
    ev2.resident.release()
    assert ev2.resident.bricks == {} and ev2.resident.nbytes == 0 and ev2.resident.worker_bytes == {}
    img = _render(ev2, camera, "xray", "trilinear", {})  # streams again
    _check_plain(img, store, volume, camera, "xray", "trilinear", {}, keypair256[1])


def test_release_reports_streaming(store, camera):
    ev2 = store.persist()
    ev2.resident.release()
    assert _render(ev2, camera, "xray", "nearest", {}).stats["resident"] is False


def test_residue_bytes_depends_only_on_the_width():
    small = [gmpy2.mpz(i) for i in range(1000)]
    del small  # gmpy2's object cache now holds one-limb integers
    after_small = residue_bytes(64)
    big = [gmpy2.mpz(2) ** 600 + i for i in range(1000)]
    del big  # ... now ten-limb ones, which the next conversions reuse
    assert residue_bytes(64) == after_small


# -- a distributed cluster of two workers ------------------------------------------------------------


def test_persist_spreads_bricks_over_both_workers(store, cluster):
    per_ct = _clean_residue_bytes(store.meta.ciphertext_bytes)
    with cluster.as_current():
        ev2 = store.persist()
    res = ev2.resident
    assert res.client is cluster and all(f.key.startswith("hevr-brick-") for f in res.bricks.values())
    res.wait()
    workers = set(cluster.scheduler_info()["workers"])
    assert set(res.worker_bytes) == workers and len(workers) == 2
    assert sum(res.worker_bytes.values()) == res.nbytes
    assert all(b > 0.3 * res.nbytes for b in res.worker_bytes.values())  # 14 and 13 bricks
    assert res.nbytes == _voxels() * (1 + K) * per_ct
    who = cluster.who_has(list(res.bricks.values()))
    holders = {k: set(v) for k, v in who.items()}
    assert len(holders) == 27 and all(len(h) == 1 for h in holders.values())
    assert set().union(*holders.values()) == workers  # both workers hold bricks
    # the placement is the planned one: two slabs of raster order, of about equal bytes
    first, second = sorted(workers)
    order = [next(iter(holders[fut.key])) for fut in res.bricks.values()]
    cut = order.index(second)
    assert set(order[:cut]) == {first} and set(order[cut:]) == {second}, order
    bricks = cluster.gather(list(res.bricks.values()))
    assert all(isinstance(b, ResidentBrick) for b in bricks)
    _check_brick_sizes(bricks)


@pytest.mark.parametrize("mode, sampling, kw", RENDERS, ids=IDS)
def test_resident_equals_streamed_distributed(store, volume, keypair256, camera, cluster, mode, sampling, kw):
    with cluster.as_current():
        ev2 = store.persist()
        ev2.resident.wait()
        a = _render(ev2, camera, mode, sampling, kw, client=cluster)
        b = _render(store, camera, mode, sampling, kw, client=cluster)
    c = _render(store, camera, mode, sampling, kw)  # no client: the default scheduler
    assert a.stats["resident"] is True and b.stats["resident"] is False and c.stats["resident"] is False
    assert _same(a, b) and _same(a, c)
    got = _check_plain(a, store, volume, camera, mode, sampling, kw, keypair256[1])
    assert np.array_equal(got, c.decrypt(keypair256[1]))


def test_resident_volume_of_another_client_streams(store, camera, cluster):
    """Bricks persisted without a client cannot serve a render on a cluster (and vice versa)."""
    local = store.persist()
    with cluster.as_current():
        img = _render(local, camera, "xray", "nearest", {}, client=cluster)
        remote = store.persist()
    assert img.stats["resident"] is False
    assert _render(remote, camera, "xray", "nearest", {}).stats["resident"] is False  # no client now
    assert _same(img, _render(store, camera, "xray", "nearest", {}))


def test_memory_limit_on_a_cluster(store, cluster):
    with cluster.as_current(), dask.config.set({RESIDENT_MEMORY_KEY: 1e-9}):
        with pytest.raises(hevr.MemoryLimitError, match="hevr.limits.resident-memory"):
            store.persist(channels="vector")
    assert not any("-vector-cpu-" in str(k) for keys in cluster.has_what().values() for k in keys)


def test_corrupt_chunk_fails_the_render_on_a_cluster(tmp_path, keypair256, volume, camera, cluster):
    hevr.encrypt_volume(volume, tmp_path / "v.zarr", keypair256[1], brick=BRICK, spacing=SPACING, progress=False)
    _corrupt(tmp_path / "v.zarr", (2, 0, 1))
    with cluster.as_current():
        ev2 = hevr.open_volume(tmp_path / "v.zarr").persist(channels="scalar")  # returns at once
        with pytest.raises(hevr.CorruptStoreError, match=r"brick \(2, 0, 1\)"):
            hevr.render(ev2, camera, progress=False, cache=False, client=cluster)
        with pytest.raises(hevr.CorruptStoreError, match=r"brick \(2, 0, 1\)"):
            ev2.resident.wait()


def test_render_with_an_explicit_non_default_client(store, camera, cluster):
    img = hevr.render(store, camera, cache=False, progress=False, client=cluster)
    assert img.stats["map_tasks"] > 0


@pytest.mark.slow
def test_resident_volume_survives_a_killed_worker(store, keypair256, camera):
    priv = keypair256[1]
    with (
        dask.config.set({"distributed.scheduler.allowed-failures": 10}),
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc,
        Client(lc) as c,
    ):
        ev2 = store.persist(client=c)
        ev2.resident.wait()
        before = _render(ev2, camera, "tf", "trilinear", {"nodes": NODES}, client=c)
        assert before.stats["resident"] is True
        pids = c.run(os.getpid)
        who = c.who_has(list(ev2.resident.bricks.values()))
        victim = sorted(pids)[0]
        lost = [k for k, ws in who.items() if victim in ws]
        assert lost  # the victim holds bricks
        os.kill(pids[victim], signal.SIGKILL)
        deadline = time.time() + 60
        while victim in c.scheduler_info()["workers"] and time.time() < deadline:
            time.sleep(0.05)
        after = _render(ev2, camera, "tf", "trilinear", {"nodes": NODES}, client=c)
        assert after.stats["resident"] is True
        ev2.resident.wait()  # every brick is (again) in memory somewhere
        assert all(f.status == "finished" for f in ev2.resident.bricks.values())
    assert _same(before, after)
    assert np.array_equal(after.decrypt(priv), before.decrypt(priv))


def test_map_tasks_run_where_their_brick_lives(store, camera, cluster):
    with cluster.as_current(), dask.config.set({"hevr.render.resident-batch": False}):
        ev2 = store.persist()
        ev2.resident.wait()
        who = cluster.who_has(list(ev2.resident.bricks.values()))
        holder = {idx: next(iter(who[f.key])) for idx, f in ev2.resident.bricks.items()}
        with get_task_stream(client=cluster) as ts:
            _render(ev2, camera, "xray", "nearest", {}, client=cluster)
    ran = {
        tuple(int(x) for x in str(t["key"]).rsplit("-", 3)[1:]): t["worker"]
        for t in ts.data
        if str(t["key"]).startswith("hevr-map-")
    }
    assert len(ran) > 5
    local = sum(ran[idx] == holder[idx] for idx in ran)
    assert local >= 0.75 * len(ran), (local, len(ran))  # work stealing may move a few; the brick stays put


@pytest.mark.parametrize("mode, sampling, kw", RENDERS, ids=IDS)
def test_tile_row_pieces_give_the_identical_image(
    store, volume, keypair256, camera, cluster, monkeypatch, mode, sampling, kw
):
    """Resident bricks split into one map task per tile row (the default from BAND_BITS on):
    the same ciphertexts as one task per brick, and as streaming."""
    with cluster.as_current(), dask.config.set({"hevr.render.resident-batch": False}):
        ev2 = store.persist()
        ev2.resident.wait()
        whole = _render(ev2, camera, mode, sampling, kw, client=cluster, tile=4)
        monkeypatch.setattr(view_mod, "BAND_BITS", 0)
        with get_task_stream(client=cluster) as ts:
            split = _render(ev2, camera, mode, sampling, kw, client=cluster, tile=4)
    streamed = _render(store, camera, mode, sampling, kw, tile=4)
    maps = [t for t in ts.data if str(t["key"]).startswith("hevr-map-")]
    if sampling == "nearest":
        assert len(maps) > split.stats["map_tasks"]  # more pieces than bricks
    else:  # trilinear rows share per-voxel powers over the whole brick: never split
        assert len(maps) == split.stats["map_tasks"]
    assert _same(whole, split) and _same(split, streamed)
    _check_plain(split, store, volume, camera, mode, sampling, kw, keypair256[1])


@pytest.mark.parametrize("mode, sampling, kw", RENDERS, ids=IDS)
def test_one_map_task_per_worker_gives_the_identical_image(
    store, volume, keypair256, camera, cluster, mode, sampling, kw
):
    """Resident bricks mapped in one task per worker (the default, issue 27): the same packed
    ciphertexts as one task per brick and as streaming; each group's task runs on the worker
    that holds its bricks, and there are no more map tasks than workers."""
    with cluster.as_current():
        ev2 = store.persist()
        ev2.resident.wait()
        who = cluster.who_has(list(ev2.resident.bricks.values()))
        holders = {next(iter(who[f.key])) for f in ev2.resident.bricks.values()}
        with get_task_stream(client=cluster) as ts:
            batched = _render(ev2, camera, mode, sampling, kw, client=cluster, tile=4)
        with dask.config.set({"hevr.render.resident-batch": False}):
            per_brick = _render(ev2, camera, mode, sampling, kw, client=cluster, tile=4)
    streamed = _render(store, camera, mode, sampling, kw, tile=4)
    maps = [t for t in ts.data if str(t["key"]).startswith("hevr-map-")]
    assert 1 <= len(maps) == batched.stats["map_tasks"] <= len(holders) < per_brick.stats["map_tasks"]
    assert {t["worker"] for t in maps} == holders  # each group where its bricks are (one group per holder)
    assert _same(batched, per_brick) and _same(batched, streamed)
    _check_plain(batched, store, volume, camera, mode, sampling, kw, keypair256[1])


class _TwoWorkers:
    """The part of a distributed client that plan_residency asks: two roomy workers."""

    def scheduler_info(self):
        return {"workers": {"tcp://a": {"memory_limit": 2**40}, "tcp://b": {"memory_limit": 2**40}}}


@pytest.mark.parametrize("bits", [256, 1024])
def test_placement_slabs_below_batch_bits_round_robin_above(tmp_path, bits):
    """Below BATCH_BITS a worker's bricks form one slab of raster order (they are mapped in one
    task); from it on brick i goes to worker i mod N (one task per brick, spread over the image)."""
    from hevr.store.resident import BATCH_BITS, plan_residency

    pub, _ = hevr.generate_keypair(bits)
    ev = hevr.encrypt_volume(np.ones((4, 4, 6), np.uint8), tmp_path / "v.zarr", pub, brick=2, progress=False)
    _, _, place, share = plan_residency(ev, None, "cpu", _TwoWorkers())
    order = [place[idx] for idx in ev.brick_indices()]
    assert len(order) == 12 and set(order) == {"tcp://a", "tcp://b"}
    if bits < BATCH_BITS:
        assert order == ["tcp://a"] * 6 + ["tcp://b"] * 6
    else:
        assert order == ["tcp://a", "tcp://b"] * 6
    assert share["tcp://a"] == share["tcp://b"]


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_batched_views_that_miss_bricks(store, volume, keypair256, cluster, sampling):
    """Views that reach only some bricks under the default batching (a slice, a zoomed camera):
    the bricks out of view are left out of the groups' tasks, the image is the streamed one (a
    KeyError before: the groups listed every resident brick, the footprints only those in view)."""
    zoom = hevr.Camera.orbit(store, azimuth=35, elevation=25, width=13, height=10, view_angle=8)
    plane = hevr.Plane.axial(store, 1, width=12, height=10)
    with cluster.as_current():
        ev2 = store.persist()
        ev2.resident.wait()
        batched = _render(ev2, zoom, "xray", sampling, {}, client=cluster)
        sliced = hevr.render_slice(ev2, plane, mode="xray", sampling=sampling, progress=False, client=cluster)
    assert batched.stats["resident"] and batched.stats["map_tasks"] <= 2
    assert _same(batched, _render(store, zoom, "xray", sampling, {}))
    assert _same(sliced, hevr.render_slice(store, plane, mode="xray", sampling=sampling, progress=False))
    _check_plain(batched, store, volume, zoom, "xray", sampling, {}, keypair256[1])


def test_resident_batch_setting():
    """``hevr.render.resident-batch``: "auto" by key size; true/false also as the strings an
    environment variable gives (DASK_HEVR__RENDER__RESIDENT_BATCH=false); anything else refused."""
    from hevr.rendering.view import _batch

    assert _batch(64) and not _batch(2048)
    for value, expected in (("False", False), ("true", True), (False, False), (True, True)):
        with dask.config.set({"hevr.render.resident-batch": value}):
            assert _batch(64) is expected and _batch(2048) is expected
    with (
        dask.config.set({"hevr.render.resident-batch": "sometimes"}),
        pytest.raises(hevr.ParameterError, match="resident-batch: expected true, false or 'auto', got 'sometimes'"),
    ):
        _batch(64)
