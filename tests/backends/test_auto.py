"""The default backend ``"auto"``: the compiled host kernels (``cuda-host``) for keys under
``COMPILED_BELOW_BITS``, ``cpu`` otherwise, the residency's backend for a resident volume — and
the same image bytes whichever it picks."""

from __future__ import annotations

import logging

import dask
import numpy as np
import pytest

import hevr
from hevr import backends
from hevr.backends import COMPILED_BELOW_BITS, get_backend, resolve_backend_name
from hevr.backends.cuda import launch
from hevr.rendering.encrypted import error_bound

SHAPE, BRICK = (6, 7, 9), (3, 4, 4)


def test_auto_resolves_by_key_size_residency_and_config():
    assert COMPILED_BELOW_BITS == 256
    assert resolve_backend_name(None, 64) == resolve_backend_name("auto", 128) == "cuda-host"
    assert resolve_backend_name(None, 255) == "cuda-host"
    assert resolve_backend_name(None, 256) == resolve_backend_name(None, 2048) == "cpu"
    assert resolve_backend_name(None) == "cpu" and get_backend().name == "cpu"  # key unknown (decryption)
    assert resolve_backend_name("cpu", 64) == "cpu"  # explicit wins
    assert resolve_backend_name(None, 64, resident="cpu") == "cpu"  # the residency's form wins under auto
    assert resolve_backend_name(None, 2048, resident="cuda-host") == "cuda-host"
    assert resolve_backend_name("cpu", 2048, resident="cuda-host") == "cpu"  # explicit: not overridden
    with dask.config.set({"hevr.backend": "cpu"}):
        assert resolve_backend_name(None, 64) == "cpu"
    with dask.config.set({"hevr.backend": "auto"}):
        assert resolve_backend_name(None, 64) == "cuda-host"


def test_auto_without_a_compiler_is_cpu(monkeypatch, caplog):
    monkeypatch.setattr(backends, "_COMPILED_OK", [])
    monkeypatch.delitem(backends._INSTANCES, "cuda-host", raising=False)  # a fresh build attempt
    monkeypatch.setenv("CC", "/nonexistent/cc")
    monkeypatch.setenv("PATH", "/nonexistent")
    with caplog.at_level(logging.INFO, logger="hevr.backends"):
        assert resolve_backend_name(None, 64) == "cpu"
    assert "small keys use the cpu backend" in caplog.text and "compiler" in caplog.text
    assert backends._COMPILED_OK == [False]  # tried once per process
    assert resolve_backend_name(None, 64) == "cpu"


def test_auto_with_a_library_that_does_not_load_is_cpu(monkeypatch, caplog):
    """An OSError on loading (a temporary folder mounted noexec, say) is no compiler either."""

    def noexec(*args, **kwargs):
        raise OSError("failed to map segment from shared object")

    monkeypatch.setattr(backends, "_COMPILED_OK", [])
    monkeypatch.delitem(backends._INSTANCES, "cuda-host", raising=False)
    monkeypatch.setattr(launch, "build_library", noexec)
    with caplog.at_level(logging.INFO, logger="hevr.backends"):
        assert resolve_backend_name(None, 64) == "cpu"
    assert "failed to map segment" in caplog.text and backends._COMPILED_OK == [False]


class _Client:
    """A distributed client's run() and scheduler address, answered as told."""

    def __init__(self, answer, address="tcp://fake:1"):
        self.answer, self.calls = answer, 0
        self.scheduler = type("S", (), {"address": address})()

    def run(self, fn):
        self.calls += 1
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


@pytest.mark.parametrize(
    "answer,want",
    [
        ({"w1": True, "w2": True}, "cuda-host"),
        ({"w1": True, "w2": False}, "cpu"),
        ({}, "cpu"),
        (OSError("worker gone"), "cpu"),
    ],
)
def test_auto_asks_every_worker_once_per_scheduler(monkeypatch, answer, want):
    """A worker without a C compiler would fail every task of a cuda-host render: auto asks the
    workers (once per scheduler) and takes cpu unless all of them build the kernels."""
    monkeypatch.setattr(backends, "_WORKERS_OK", {})
    client = _Client(answer)
    assert resolve_backend_name(None, 64, client=client) == want
    assert resolve_backend_name(None, 128, client=client) == want and client.calls == 1
    assert resolve_backend_name(None, 2048, client=client) == "cpu"


@pytest.fixture(scope="module")
def small_key_store(tmp_path_factory):
    with pytest.warns(hevr.InsecureKeyWarning):
        _, priv = hevr.generate_keypair(64)  # the arithmetic nearly free: what auto is for
    vol = np.random.default_rng(3).integers(0, 200, SHAPE).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(
            vol,
            tmp_path_factory.mktemp("auto") / "v.zarr",
            priv,
            brick=BRICK,
            vector_dims=3,
            value_range=(0, 255),
            progress=False,
        )
    return ev, vol, priv


@pytest.mark.parametrize("mode,sampling", [("xray", "nearest"), ("xray", "trilinear"), ("tf", "nearest")])
def test_auto_render_of_a_small_key_is_compiled_and_identical(small_key_store, mode, sampling):
    ev, vol, priv = small_key_store
    cam = hevr.Camera.orbit(ev, azimuth=25, elevation=15, width=9, height=8)
    kw = {"nodes": [(0.2, "blue"), (0.8, "red")]} if mode == "tf" else {}
    with dask.config.set(scheduler="sync"):
        auto = hevr.render(ev, cam, mode, sampling, progress=False, cache=False, **kw)
        cpu = hevr.render(ev, cam, mode, sampling, progress=False, cache=False, backend="cpu", **kw)
    assert auto.stats["backend"] == "cuda-host" and cpu.stats["backend"] == "cpu"
    assert len(auto.ciphertexts) == len(cpu.ciphertexts)
    for a, b in zip(auto.ciphertexts, cpu.ciphertexts):
        np.testing.assert_array_equal(a, b)
    ref = hevr.render_plain(vol, cam, mode, sampling, vector_dims=3, value_range=(0, 255), **kw)
    assert np.count_nonzero(ref) > 5
    assert np.all(np.abs(auto.decrypt(priv) - ref) <= error_bound(ev, cam, mode, sampling, **kw))


def test_auto_render_takes_the_residency_backend(small_key_store, caplog):
    ev = small_key_store[0]
    cam = hevr.Camera.orbit(ev, azimuth=25, elevation=15, width=9, height=8)
    with dask.config.set(scheduler="sync"):
        ref = hevr.render(ev, cam, progress=False, cache=False, backend="cpu")
        for explicit in ("cpu", "cuda-host"):
            res = ev.persist("scalar", backend=explicit)
            with caplog.at_level(logging.WARNING, logger="hevr"):
                img = hevr.render(res, cam, progress=False, cache=False)
            assert img.stats["resident"] and img.stats["backend"] == explicit
            assert "streaming from the store" not in caplog.text
            for a, b in zip(img.ciphertexts, ref.ciphertexts):
                np.testing.assert_array_equal(a, b)
        auto = ev.persist("scalar")
    assert auto.resident.backend == "cuda-host"  # persisted under auto: by the key's size


def test_stats_name_the_backend_that_computed_reused_sums(small_key_store):
    ev = small_key_store[0]
    cam = hevr.Camera.orbit(ev, azimuth=5, elevation=35, width=7, height=6)
    hevr.clear_cache()
    with dask.config.set(scheduler="sync"):
        first = hevr.render(ev, cam, progress=False, backend="cpu")
        again = hevr.render(ev, cam, progress=False)  # auto, the same view: the cached packed sums, no task
    assert first.stats["backend"] == "cpu" and again.stats["reused_ray_sums"] and again.stats["finish_tasks"] == 0
    assert again.stats["backend"] == "cpu"
