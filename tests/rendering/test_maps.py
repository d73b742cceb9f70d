"""The map tasks (hevr.rendering.pipeline.maps): a worker's group of resident bricks on a GPU-resident
backend — one group for the local device, and trilinear rows of every brick in one plan (one
kernel call, not one per brick) — give the cpu image byte for byte. The ``cuda-host`` kernels
stand in for a device here (their launcher's ``residence`` set to ``"device"``), so these paths
run in CI; ``tests/backends/test_cuda_device.py`` runs them over FakeCupy too."""

from __future__ import annotations

import dask
import numpy as np
import pytest

import hevr
from hevr.backends.cuda.launch import HostLauncher
from hevr.rendering.pipeline import maps

NODES = [(0.3, "red"), (0.8, "blue")]


@pytest.fixture
def device_like(monkeypatch):
    """``cuda-host`` with its residues treated as on a device (the paths a GPU takes)."""
    monkeypatch.setattr(HostLauncher, "residence", "device")
    calls = []
    real = maps.brick_ray_products_multi

    def counted(*args, **kwargs):
        calls.append(len(args[1]) - 1)  # rows
        return real(*args, **kwargs)

    monkeypatch.setattr(maps, "brick_ray_products_multi", counted)
    return calls


@pytest.mark.parametrize(
    "mode, sampling, kw", [("xray", "trilinear", {}), ("tf", "trilinear", {"nodes": NODES}), ("xray", "nearest", {})]
)
def test_a_device_group_is_one_kernel_call_and_the_cpu_image(device_like, tmp_path, keypair256, mode, sampling, kw):
    vol = np.random.default_rng(3).integers(0, 256, (12, 14, 16)).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[1], brick=6, vector_dims=3, progress=False)
        cam = hevr.Camera.orbit(ev, azimuth=35, elevation=25, width=20, height=18)
        want = hevr.render(ev, cam, mode, sampling, backend="cpu", progress=False, cache=False, **kw)
        rv = ev.persist(backend="cuda-host")
        device_like.clear()
        got = hevr.render(rv, cam, mode, sampling, backend="cuda-host", progress=False, cache=False, **kw)
    assert got.stats["resident"] and got.stats["map_tasks"] == 1  # the process's one device: one group
    assert len(device_like) == 1 and device_like[0] > 0  # every brick's rows in one call: 18 bricks, one launch
    assert len(want.ciphertexts) == len(got.ciphertexts)
    for x, y in zip(want.ciphertexts, got.ciphertexts):
        np.testing.assert_array_equal(x, y)


def test_host_residues_keep_per_thread_groups_and_per_brick_trilinear(tmp_path, keypair256, monkeypatch):
    """The rules are the device's only: host backends keep their groups and per-brick trilinear maps."""
    calls = []
    real = maps.brick_ray_products_multi
    monkeypatch.setattr(maps, "brick_ray_products_multi", lambda *a, **k: calls.append(1) or real(*a, **k))
    vol = np.random.default_rng(3).integers(0, 256, (12, 14, 16)).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[1], brick=6, progress=False)
        cam = hevr.Camera.orbit(ev, azimuth=35, elevation=25, width=20, height=18)
        rv = ev.persist(backend="cuda-host")
        img = hevr.render(rv, cam, "xray", "trilinear", backend="cuda-host", progress=False, cache=False)
    assert img.stats["map_tasks"] == min(len(rv.resident.bricks), dask.system.CPU_COUNT) and len(calls) > 1
