"""Size limits of a render (hevr.rendering.planning.planner.check_render_size) and of a brick
(hevr.core.validate.check_brick): impossible work is refused with a hevr error naming the
field, within a second and a few MB, before anything is allocated per pixel or sample."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import tracemalloc
import warnings
from collections.abc import Callable
from typing import Any

import dask
import numpy as np
import pytest

import hevr
from hevr.core.validate import MAX_BRICK_EDGE, MAX_BRICK_VOXELS, check_brick
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.planning.planner import (
    DEFAULT_MAX_PIXELS,
    DEFAULT_MAX_SAMPLES,
    MAX_PIXELS_KEY,
    MAX_SAMPLES_KEY,
    check_render_size,
    max_ray_samples,
    render_limits,
)
from hevr.rendering.reference import plain

SECONDS = 1.0  # generous: every refusal here takes milliseconds
PEAK_BYTES = 4 << 20  # "a few MB" of Python-visible allocations


def refused(error: type[Exception], fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[str, float, int]:
    """Call ``fn``; it must raise ``error``. Returns (message, seconds, tracemalloc peak)."""
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(error) as info:
            fn(*args, **kwargs)
        seconds = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return str(info.value), seconds, peak


@pytest.fixture(scope="module")
def ev(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        pub, _ = hevr.generate_keypair(128)
    vol = np.arange(6 * 7 * 8, dtype=np.uint8).reshape(6, 7, 8)
    return hevr.encrypt_volume(vol, tmp_path_factory.mktemp("lim") / "v.zarr", pub, brick=4, progress=False)


# -- the rule -------------------------------------------------------------------------------
def test_defaults_and_the_paper_setting_fit() -> None:
    assert render_limits() == (DEFAULT_MAX_PIXELS, DEFAULT_MAX_SAMPLES) == (4096 * 4096, 2**31)
    shape = (100, 100, 100)
    assert check_render_size(Camera.orbit(shape, width=150, height=150), shape, (1, 1, 1), 1.0) is None
    check_render_size(Camera.orbit((200,) * 3, width=150, height=150), (200,) * 3, (1, 1, 1), 0.5)


@pytest.mark.parametrize("width, height", [(16384, 16384), (4097, 4096), (10**9, 10**9), (1, 10**12)])
def test_too_many_pixels_is_refused_at_once(width: int, height: int) -> None:
    cam = Camera.orbit((100, 100, 100), width=width, height=height)
    msg, seconds, peak = refused(hevr.RenderPlanError, check_render_size, cam, (100, 100, 100), (1, 1, 1), 1.0)
    assert msg.startswith("width, height: expected") and f"{width}x{height}" in msg and MAX_PIXELS_KEY in msg
    assert seconds < SECONDS and peak < PEAK_BYTES


@pytest.mark.parametrize("step", [1e-9, 1e-5, 1e-300, 5e-324])
def test_too_many_samples_is_refused_at_once(step: float) -> None:
    shape = (100, 100, 100)
    cam = Camera.orbit(shape, width=64, height=64)
    msg, seconds, peak = refused(hevr.RenderPlanError, check_render_size, cam, shape, (1, 1, 1), step)
    assert msg.startswith("step: expected at most")
    assert seconds < SECONDS and peak < PEAK_BYTES


def test_exact_count_decides_when_the_public_bound_is_too_loose() -> None:
    shape, spacing = (10, 10, 10), (1.0, 1.0, 1.0)
    cam = Camera.orbit(shape, azimuth=30, elevation=20, width=64, height=64)
    exact = int(cast_rays(cam, shape, spacing, 0.5).n_samples.sum())
    bound = 64 * 64 * max_ray_samples(shape, spacing, 0.5)
    assert exact < bound  # most rays miss or cross less than the diagonal
    with dask.config.set({MAX_SAMPLES_KEY: exact}):
        rays = check_render_size(cam, shape, spacing, 0.5)  # counted exactly: the rays come back
    assert np.array_equal(rays.n_samples, cast_rays(cam, shape, spacing, 0.5).n_samples)
    assert check_render_size(cam, shape, spacing, 0.5) is None  # the public bound decided: nothing cast
    with dask.config.set({MAX_SAMPLES_KEY: exact - 1}):
        msg, _, _ = refused(hevr.RenderPlanError, check_render_size, cam, shape, spacing, 0.5)
    assert msg.startswith("step:") and MAX_SAMPLES_KEY in msg


@pytest.mark.parametrize(
    "azimuth, elevation, parallel", [(0, 0, True), (30, 20, False), (45, 35.26, True), (170, -60, False)]
)
def test_public_bound_bounds_every_ray(azimuth: float, elevation: float, parallel: bool) -> None:
    shape, spacing = (6, 9, 13), (0.7, 1.0, 1.9)
    cam = Camera.orbit(shape, azimuth, elevation, width=31, height=23, spacing=spacing, parallel=parallel)
    for step in (0.1, 0.5, 1.0, 3.0):
        assert cast_rays(cam, shape, spacing, step).n_samples.max() <= max_ray_samples(shape, spacing, step)


def test_limits_come_from_dask_config() -> None:
    shape = (8, 8, 8)
    with dask.config.set({MAX_PIXELS_KEY: 100}):
        assert render_limits()[0] == 100
        check_render_size(Camera.orbit(shape, width=10, height=10), shape, (1, 1, 1), 1.0)
        msg, _, _ = refused(
            hevr.RenderPlanError, check_render_size, Camera.orbit(shape, width=11, height=10), shape, (1, 1, 1), 1.0
        )
        assert "width, height" in msg and "at most 100 pixels" in msg
    with dask.config.set({"hevr.limits.max_samples": "50"}):  # '_' and '-' are one key; strings from env
        assert render_limits()[1] == 50
        with pytest.raises(hevr.RenderPlanError, match="^step: expected at most 50 samples"):
            check_render_size(Camera.orbit(shape, width=10, height=10), shape, (1, 1, 1), 1.0)


@pytest.mark.parametrize("value", [0, -5, "lots", 1.5, 2**60, True, [1]])
def test_bad_limit_in_config_is_a_parameter_error(value: Any) -> None:
    with dask.config.set({MAX_PIXELS_KEY: value}), pytest.raises(hevr.ParameterError, match=MAX_PIXELS_KEY):
        render_limits()


def test_limits_from_the_environment() -> None:
    code = (
        "import hevr, sys\n"
        "from hevr.rendering.planning.planner import render_limits\n"
        "print(render_limits())\n"
        "try:\n"
        "    hevr.render_plain(hevr.phantom(8), hevr.Camera.orbit((8, 8, 8), width=8, height=8))\n"
        "except hevr.RenderPlanError as e:\n"
        "    print(e)\n"
    )
    env = dict(os.environ, DASK_HEVR__LIMITS__MAX_PIXELS="50", DASK_HEVR__LIMITS__MAX_SAMPLES="1000")
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.splitlines()[:2]
    assert first == "(50, 1000)" and second.startswith("width, height: expected an image of at most 50 pixels")


def test_camera_type_is_checked_first() -> None:
    with pytest.raises(hevr.ParameterError, match="^camera: expected a hevr.Camera"):
        check_render_size("front", (2, 2, 2), (1, 1, 1), 1.0)
    with pytest.raises(hevr.ParameterError, match="step"):
        check_render_size(Camera.orbit((2, 2, 2)), (2, 2, 2), (1, 1, 1), float("nan"))


# -- every entry point applies it -------------------------------------------------------------
def test_render_plain_refuses_fast() -> None:
    vol = np.zeros((100, 100, 100), np.uint8)
    big = Camera.orbit(vol.shape, width=16384, height=16384)
    msg, seconds, peak = refused(hevr.RenderPlanError, hevr.render_plain, vol, big)
    assert msg.startswith("width, height:") and seconds < SECONDS and peak < PEAK_BYTES
    small = Camera.orbit(vol.shape, width=64, height=64)
    msg, seconds, peak = refused(hevr.RenderPlanError, hevr.render_plain, vol, small, step=1e-9)
    assert msg.startswith("step:") and seconds < SECONDS and peak < PEAK_BYTES


@pytest.mark.parametrize("fn", [hevr.render, hevr.error_bound], ids=["render", "error_bound"])
def test_encrypted_entry_points_refuse_fast(ev, fn: Callable[..., Any]) -> None:
    kw = {"progress": False} if fn is hevr.render else {}
    big = Camera.orbit(ev, width=16384, height=16384)
    msg, seconds, peak = refused(hevr.RenderPlanError, fn, ev, big, **kw)
    assert msg.startswith("width, height:") and seconds < SECONDS and peak < PEAK_BYTES
    cam = Camera.orbit(ev, width=16, height=16)
    msg, seconds, peak = refused(hevr.RenderPlanError, fn, ev, cam, step=1e-9, **kw)
    assert msg.startswith("step:") and seconds < SECONDS and peak < PEAK_BYTES


def test_cast_rays_never_overflows() -> None:
    cam = Camera.orbit((100, 100, 100), width=4, height=4)
    with pytest.raises(hevr.RenderPlanError, match="^step: expected at most 2\\^53 samples along one ray"):
        cast_rays(cam, (100, 100, 100), (1, 1, 1), 1e-300)
    huge = cast_rays(cam, (3, 3, 3), (1e308, 1e308, 1e308), 1.0)  # the box's size overflows to inf
    assert (huge.n_samples >= 0).all()


def test_long_rays_are_summed_in_pieces(monkeypatch: pytest.MonkeyPatch) -> None:
    shape = (6, 7, 8)
    vol = np.random.default_rng(5).random(shape)
    cam = Camera.orbit(shape, 15, 25, width=9, height=7)
    full = {s: hevr.render_plain(vol, cam, sampling=s, step=0.25) for s in ("nearest", "trilinear")}
    monkeypatch.setattr(plain, "_RAY_PIECE", 3)
    monkeypatch.setattr(plain, "_CHUNK_SAMPLES", 5)
    for s, ref in full.items():
        np.testing.assert_allclose(hevr.render_plain(vol, cam, sampling=s, step=0.25), ref, rtol=1e-12, atol=0)


# -- bricks -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "brick, needle",
    [
        (10**9, "at most 4096 voxels per axis"),
        ((1, 1, 4097), "per axis"),
        (257, "at most 16777216 voxels per brick"),
        ((512, 256, 256), "voxels per brick"),
    ],
)
def test_absurd_bricks_are_refused(brick: Any, needle: str) -> None:
    with pytest.raises(hevr.ParameterError, match="^brick: expected") as info:
        check_brick(brick)
    assert needle in str(info.value)


def test_brick_limits_and_clipping() -> None:
    assert check_brick(256) == (256, 256, 256) and 256**3 == MAX_BRICK_VOXELS
    assert check_brick((1, 4096, 4096)) == (1, MAX_BRICK_EDGE, MAX_BRICK_EDGE)
    assert check_brick(4096, shape=(20, 30, 40)) == (20, 30, 40)  # within the caps: clipped to the volume
    assert check_brick((5, 1000, 7), shape=(20, 30, 40)) == (5, 30, 7)
    with pytest.raises(hevr.ParameterError, match="at most 4096 voxels per axis"):  # absurd: refused even so
        check_brick(10**9, shape=(20, 30, 40))
    with pytest.raises(hevr.ParameterError, match="voxels per brick"):
        check_brick(300, shape=(300, 300, 300))


def test_encrypt_volume_refuses_an_absurd_brick(tmp_path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        pub, _ = hevr.generate_keypair(128)
    vol = np.zeros((8, 8, 8), np.uint8)
    msg, seconds, peak = refused(
        hevr.ParameterError, hevr.encrypt_volume, vol, tmp_path / "v.zarr", pub, brick=10**9, progress=False
    )
    assert msg.startswith("brick: expected") and seconds < SECONDS and peak < PEAK_BYTES
    assert not (tmp_path / "v.zarr").exists()


# -- density encodings --------------------------------------------------------------------------
@pytest.mark.parametrize("dims", [65, 10**6, 10**12])
def test_absurd_vector_dims_are_refused(dims: int) -> None:
    vol = np.zeros((4, 4, 4), np.uint8)
    cam = Camera.orbit(vol.shape, width=4, height=4)
    msg, seconds, peak = refused(
        hevr.ParameterError, hevr.render_plain, vol, cam, mode="emphasize", density=0.5, vector_dims=dims
    )
    assert msg.startswith("vector_dims: expected an integer in [2, 64]") and seconds < SECONDS and peak < PEAK_BYTES
