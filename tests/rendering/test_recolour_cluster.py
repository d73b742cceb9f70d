"""Re-colouring on a distributed client: the cached ray sums stay on the workers."""

from __future__ import annotations

import numpy as np
import pytest
from distributed import Future, get_task_stream

import hevr
from hevr.rendering.encrypted import error_bound
from hevr.rendering.pipeline import cache as render_cache

SHAPE = (7, 9, 11)
BRICK = (3, 4, 5)
SPACING = (1.0, 0.8, 1.3)
K = 4
NODES = [(0.279, "blue"), (0.797, "red")]
OTHER = [(0.1, "#00ff00"), (0.5, "yellow"), (0.9, (0.2, 0.4, 1.0))]


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(23).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    return hevr.encrypt_volume(
        volume,
        tmp_path_factory.mktemp("recolour") / "v.zarr",
        keypair256[1],
        brick=BRICK,
        spacing=SPACING,
        vector_dims=K,
        progress=False,
    )


@pytest.fixture(autouse=True)
def _fresh_cache():
    hevr.clear_cache()
    yield
    hevr.clear_cache()


class _GatherLog:
    """Records the keys of every gather the client makes, and of those actually fetched remotely."""

    def __init__(self, client):
        self.client, self.requested, self.fetched = client, [], []
        self._gather, self._remote = client._gather, client._gather_remote

    async def gather(self, futures, *args, **kwargs):
        from distributed.utils_comm import unpack_remotedata

        _, found = unpack_remotedata(futures, byte_keys=True)
        self.requested.extend(f.key for f in found)
        return await self._gather(futures, *args, **kwargs)

    async def remote(self, *args, **kwargs):
        self.fetched.extend(self.client._gather_keys or ())
        return await self._remote(*args, **kwargs)

    def __enter__(self):
        self.client._gather, self.client._gather_remote = self.gather, self.remote
        return self

    def __exit__(self, *exc):
        self.client._gather, self.client._gather_remote = self._gather, self._remote


def _check_plain(img, store, volume, cam, priv, **kw):
    ref = hevr.render_plain(volume, cam, spacing=SPACING, vector_dims=K, **kw)
    assert np.all(np.abs(img.decrypt(priv) - ref) <= error_bound(store, cam, finish=img.finish, **kw))
    assert np.count_nonzero(ref) > 10


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_recolour_keeps_ray_sums_on_the_workers(store, volume, keypair256, cluster, sampling):
    priv = keypair256[1]
    cam = hevr.Camera.orbit(store, azimuth=-40, elevation=20, width=24, height=20)
    n_tiles = -(-24 // 8) * -(-20 // 8)
    with cluster.as_current():
        first = hevr.render(
            store, cam, mode="tf", nodes=NODES, sampling=sampling, tile=8, client=cluster, progress=False
        )
        assert not first.stats["reused_ray_sums"] and first.stats["map_tasks"] > 0
        assert first.stats["gathered_bytes"] == sum(int(c.nbytes) for c in first.ciphertexts)
        _check_plain(first, store, volume, cam, priv, mode="tf", nodes=NODES, sampling=sampling)

        assert len(render_cache._CACHE) == 1
        sums = next(iter(render_cache._CACHE.values()))
        assert sums.client is cluster and set(sums.tiles) == set(range(n_tiles))
        futures = [v for v in sums.tiles.values() if v is not None]
        assert len(futures) > 1 and all(isinstance(f, Future) for f in futures)
        assert all(f.status == "finished" for f in futures)
        sum_keys = {f.key for f in futures}
        assert all(k.startswith(("hevr-merge-", "hevr-part-")) for k in sum_keys)
        assert set(cluster.who_has(futures)) == sum_keys and all(cluster.who_has(futures).values())

        # finished on the client, another colouring of the view is the packed sums it already has: no task
        with get_task_stream(client=cluster) as ts:
            same = hevr.render(
                store, cam, mode="emphasize", density=0.42, sampling=sampling, tile=8, client=cluster, progress=False
            )
        assert same.stats["finish_tasks"] == 0 and same.stats["gathered_bytes"] == 0 and not ts.data
        assert all(np.array_equal(a, b) for a, b in zip(same.ciphertexts, first.ciphertexts))
        _check_plain(same, store, volume, cam, priv, mode="emphasize", density=0.42, sampling=sampling)

        # finished on the server (the paper's way), the finishing runs next to the sums on the workers
        for kw in ({"mode": "tf", "nodes": OTHER}, {"mode": "emphasize", "density": 0.42}):
            with _GatherLog(cluster) as log, get_task_stream(client=cluster) as ts:
                again = hevr.render(
                    store, cam, sampling=sampling, tile=8, client=cluster, progress=False, finish="server", **kw
                )
            assert again.stats["reused_ray_sums"] is True and again.stats["map_tasks"] == 0
            assert again.stats["finish_tasks"] >= n_tiles  # at least one finishing task per tile
            packed = sum(int(c.nbytes) for c in again.ciphertexts)
            assert again.stats["gathered_bytes"] == packed > 0
            # only the finishing tasks ran, and only their packed tiles came to the client
            ran = [str(t["key"]) for t in ts.data]
            assert len(ran) == again.stats["finish_tasks"] and all(k.startswith("hevr-finish-") for k in ran), ran
            assert log.requested and all(str(k).startswith("hevr-finish-") for k in log.requested)
            assert log.fetched and set(log.fetched) <= set(log.requested)
            assert not set(log.fetched) & sum_keys
            _check_plain(again, store, volume, cam, priv, sampling=sampling, **kw)

        # the sums are still on the workers, and far bigger than what the re-colour sent back
        assert all(f.status == "finished" for f in futures)
        gathered = cluster.gather(futures)
    sums_bytes = sum(int(r.nbytes) + int(c.nbytes) for r, c in gathered)
    assert all(c.shape[1] == K for _, c in gathered)  # one ciphertext per vector component and ray
    assert again.stats["gathered_bytes"] < 0.5 * sums_bytes, (again.stats["gathered_bytes"], sums_bytes)


def test_recolour_matches_a_fresh_render(store, keypair256, cluster):
    """The re-coloured image is exactly what a render without the cache gives."""
    priv = keypair256[1]
    cam = hevr.Camera.orbit(store, azimuth=70, elevation=-10, width=16, height=16, parallel=True)
    with cluster.as_current():
        hevr.render(store, cam, mode="emphasize", density=0.3, sampling="trilinear", client=cluster, progress=False)
        again = hevr.render(store, cam, mode="tf", nodes=OTHER, sampling="trilinear", client=cluster, progress=False)
        fresh = hevr.render(
            store, cam, mode="tf", nodes=OTHER, sampling="trilinear", client=cluster, progress=False, cache=False
        )
    assert again.stats["reused_ray_sums"] and not fresh.stats["reused_ray_sums"]
    assert all(np.array_equal(a, b) for a, b in zip(again.ciphertexts, fresh.ciphertexts))
    assert np.array_equal(again.decrypt(priv), fresh.decrypt(priv))


def test_cluster_sums_do_not_serve_another_scheduler(store, keypair256, cluster):
    """Futures belong to their client: a render on the default scheduler recomputes (and vice versa)."""
    cam = hevr.Camera.orbit(store, azimuth=15, elevation=35, width=12, height=12)
    with cluster.as_current():
        hevr.render(store, cam, mode="tf", nodes=NODES, client=cluster, progress=False)
    local = hevr.render(store, cam, mode="tf", nodes=OTHER, progress=False)  # no client: default scheduler
    assert not local.stats["reused_ray_sums"] and local.stats["map_tasks"] > 0
    sums = next(iter(render_cache._CACHE.values()))
    assert sums.client is None and all(not isinstance(v, Future) for v in sums.tiles.values())
    again = hevr.render(store, cam, mode="tf", nodes=NODES, progress=False)
    assert again.stats["reused_ray_sums"]
    # on a single machine the client holds the sums, so the first render counted them as gathered
    assert local.stats["gathered_bytes"] > sum(int(c.nbytes) for c in local.ciphertexts)
    with cluster.as_current():
        remote = hevr.render(store, cam, mode="tf", nodes=NODES, client=cluster, progress=False)
    assert not remote.stats["reused_ray_sums"] and remote.stats["map_tasks"] == local.stats["map_tasks"]
    assert np.array_equal(remote.decrypt(keypair256[1]), again.decrypt(keypair256[1]))
