"""Tests for hevr.rendering.geometry.weights: per-brick integer weights of the encrypted path."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr.rendering.geometry.weights as weights_mod
from hevr.errors import ParameterError
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import (
    BrickWeights,
    brick_bounds,
    brick_grid,
    brick_weights,
    touched_bricks,
)
from hevr.rendering.planning.modes import combination_matrix, make_spec, normalisation_factor
from hevr.rendering.reference.plain import render_plain
from hevr.volume.density import encode_density, normalize_density

SHAPE, BRICK, SPACING, STEP = (7, 9, 11), (3, 4, 5), (0.8, 1.1, 1.3), 0.7
_NODES = [(0.279, (0, 0, 1)), (0.797, "red"), (0.5, "#00ff00")]
_MODE_KW = {"xray": {}, "emphasize": {"density": 0.653}, "tf": {"nodes": _NODES}}
_VOL = np.random.default_rng(11).integers(0, 256, SHAPE).astype(np.uint8)
_CACHE: dict = {}


def _camera(parallel: bool) -> Camera:
    return Camera.orbit(SHAPE, azimuth=33, elevation=21, width=13, height=11, spacing=SPACING, parallel=parallel)


def _dense(bw: BrickWeights, shape: tuple, bounds: tuple, n_rays: int) -> np.ndarray:
    """Global (n_rays, nz, ny, nx) int64 weights of one brick."""
    out = np.zeros((n_rays,) + shape, dtype=np.int64)
    local = tuple(b - a for a, b in bounds)
    z, y, x = np.unravel_index(bw.voxels, local)
    rays = np.repeat(bw.rays, np.diff(bw.indptr))
    np.add.at(out, (rays, z + bounds[0][0], y + bounds[1][0], x + bounds[2][0]), bw.weights)
    return out


def _check_invariants(bw: BrickWeights, local_size: int, sampling: str) -> None:
    assert bw.rays.dtype == bw.indptr.dtype == bw.voxels.dtype == bw.weights.dtype == np.int64
    assert np.all(np.diff(bw.rays) > 0)
    assert bw.indptr[0] == 0 and bw.indptr[-1] == bw.n_pairs and len(bw.indptr) == len(bw.rays) + 1
    assert np.all(np.diff(bw.indptr) > 0)
    assert np.all(bw.weights > 0)
    assert np.all((bw.voxels >= 0) & (bw.voxels < local_size))
    keys = np.repeat(bw.rays, np.diff(bw.indptr)) * local_size + bw.voxels
    assert np.all(np.diff(keys) > 0)  # one entry per distinct (ray, voxel), sorted
    assert bw.exponent == (0 if sampling == "nearest" else -3)


def _split_and_full(parallel: bool, sampling: str):
    key = (parallel, sampling)
    if key not in _CACHE:
        rs = cast_rays(_camera(parallel), SHAPE, SPACING, STEP)
        full = brick_weights(rs, SHAPE, SPACING, SHAPE, (0, 0, 0), sampling, STEP)
        _check_invariants(full, int(np.prod(SHAPE)), sampling)
        split = np.zeros((rs.n_rays,) + SHAPE, dtype=np.int64)
        nonempty = []
        for idx in itertools.product(*map(range, brick_grid(SHAPE, BRICK))):
            bw = brick_weights(rs, SHAPE, SPACING, BRICK, idx, sampling, STEP)
            bounds = brick_bounds(SHAPE, BRICK, idx)
            _check_invariants(bw, math.prod(b - a for a, b in bounds), sampling)
            assert bw.brick == idx
            if bw.n_pairs:
                nonempty.append(idx)
            split += _dense(bw, SHAPE, bounds, rs.n_rays)
        _CACHE[key] = rs, full, split, nonempty
    return _CACHE[key]


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_bricks_sum_to_whole_volume_weights(sampling: str, parallel: bool) -> None:
    rs, full, split, nonempty = _split_and_full(parallel, sampling)
    np.testing.assert_array_equal(split, _dense(full, SHAPE, brick_bounds(SHAPE, SHAPE, (0, 0, 0)), rs.n_rays))
    touched = touched_bricks(rs, SHAPE, SPACING, BRICK, sampling, STEP)
    assert touched == sorted(touched) and len(nonempty) > 8
    if sampling == "nearest":
        assert touched == nonempty
    else:
        assert set(nonempty) <= set(touched)
    if sampling == "nearest":  # nearest weights are sample counts
        np.testing.assert_array_equal(split.reshape(rs.n_rays, -1).sum(axis=1), rs.n_samples)
    else:
        np.testing.assert_allclose(split.reshape(rs.n_rays, -1).sum(axis=1) * 1e-3, rs.n_samples, atol=0.5)


def _field(mode: str, k: int = 4) -> np.ndarray:
    """Per-voxel quantity the weights multiply: raw value or e(density) @ M, (nvox, C)."""
    if mode == "xray":
        return _VOL.reshape(-1, 1).astype(np.float64)
    spec = make_spec(mode, "nearest", STEP, _MODE_KW[mode].get("density"), _MODE_KW[mode].get("nodes"), k)
    enc = encode_density(normalize_density(_VOL.reshape(-1), (0, 255)), k)
    return enc @ combination_matrix(spec, k)


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode", ["xray", "emphasize", "tf"])
def test_weights_reproduce_render_plain(mode: str, sampling: str, parallel: bool) -> None:
    rs, full, split, _ = _split_and_full(parallel, sampling)
    spec = make_spec(mode, sampling, STEP, _MODE_KW[mode].get("density"), _MODE_KW[mode].get("nodes"), 4)
    factor = normalisation_factor(spec)
    q = _field(mode)
    sums = split.reshape(rs.n_rays, -1).astype(np.float64) @ q * 10.0**full.exponent
    n = rs.n_samples.astype(np.float64)[:, None] * factor
    img = np.divide(sums, n, out=np.zeros_like(sums), where=n > 0)
    ref = render_plain(
        _VOL, _camera(parallel), mode=mode, sampling=sampling, step=STEP, spacing=SPACING, **_MODE_KW[mode]
    ).reshape(rs.n_rays, -1)
    if sampling == "nearest":
        np.testing.assert_allclose(img, ref, rtol=1e-12, atol=1e-12)
    else:
        # Module docstring bound: P * 0.5e-3 * max|q| / (n*factor) per pixel with P <= 8n pairs.
        bound = 4 * 10.0**full.exponent * np.abs(q).max() / factor
        err = np.abs(img - ref)
        assert err.max() <= bound + 1e-9
        assert err.max() > 0  # rounding is visible, so the check is not vacuous


def _naive_trilinear_weights(rs, shape, spacing, step) -> dict:
    """Float sum of trilinear weights per (ray, voxel), written out sample by sample."""
    nz, ny, nx = shape
    out: dict = {}
    for r in np.flatnonzero(rs.n_samples):
        for kk in range(int(rs.n_samples[r])):
            p = (rs.origins[r] + (rs.t_enter[r] + kk * step) * rs.directions[r]) / np.asarray(spacing)
            b = np.floor(p).astype(int)
            f = p - b
            for dx, dy, dz in itertools.product((0, 1), repeat=3):
                w = (f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1]) * (f[2] if dz else 1 - f[2])
                v = (min(max(b[2] + dz, 0), nz - 1), min(max(b[1] + dy, 0), ny - 1), min(max(b[0] + dx, 0), nx - 1))
                out[(r, v)] = out.get((r, v), 0.0) + w
    return out


def test_trilinear_weights_are_rounded_sums() -> None:
    rs, full, split, _ = _split_and_full(False, "trilinear")
    naive = _naive_trilinear_weights(rs, SHAPE, SPACING, STEP)
    dense = np.zeros_like(split, dtype=np.float64)
    for (r, v), w in naive.items():
        dense[(r,) + v] = w
    assert np.abs(split * 1e-3 - dense).max() <= 0.5e-3 + 1e-12


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("offset", [0.0, 0.5])
def test_exact_halves_and_faces_split_consistently(sampling: str, offset: float) -> None:
    # Pixel centres on voxel columns (faces included) or exactly half way between them,
    # where floor(p + 0.5) rounds up -- across the brick boundaries at x = 5 and y = 4.
    shape, brick, spacing = (5, 9, 11), (2, 4, 5), (1.0, 1.0, 1.0)
    nz, ny, nx = shape
    cx, cy = (nx - 1) / 2 + offset, (ny - 1) / 2 + offset
    cam = Camera((cx, cy, 10.0), (cx, cy, 0.0), width=nx, height=ny, parallel=True, parallel_scale=ny / 2)
    rs = cast_rays(cam, shape, spacing, 0.5)
    vol = np.random.default_rng(5).random(shape)
    full = brick_weights(rs, shape, spacing, shape, (0, 0, 0), sampling, 0.5)
    split = sum(
        _dense(
            brick_weights(rs, shape, spacing, brick, i, sampling, 0.5), shape, brick_bounds(shape, brick, i), rs.n_rays
        )
        for i in itertools.product(*map(range, brick_grid(shape, brick)))
    )
    np.testing.assert_array_equal(split, _dense(full, shape, brick_bounds(shape, shape, (0, 0, 0)), rs.n_rays))
    n = rs.n_samples
    img = (split.reshape(rs.n_rays, -1) @ vol.reshape(-1)) * 10.0**full.exponent
    img = np.divide(img, n, out=np.zeros_like(img), where=n > 0)
    ref = render_plain(vol, cam, sampling=sampling, step=0.5, spacing=spacing).reshape(-1)
    tol = 0 if sampling == "nearest" else 4e-3
    np.testing.assert_allclose(img, ref, atol=tol + 1e-12, rtol=0)


@settings(max_examples=30, deadline=None)
@given(
    shape=st.tuples(*[st.integers(1, 7)] * 3),
    brick=st.tuples(*[st.integers(1, 4)] * 3),
    spacing=st.tuples(*[st.sampled_from([0.5, 1.0, 1.3])] * 3),
    step=st.sampled_from([0.3, 0.5, 1.0, 1.7]),
    azimuth=st.sampled_from([0.0, 90.0, -45.0, 33.3, 180.0]),
    elevation=st.sampled_from([0.0, 90.0, -90.0, 21.0]),
    parallel=st.booleans(),
    sampling=st.sampled_from(["nearest", "trilinear"]),
)
def test_split_invariance_property(shape, brick, spacing, step, azimuth, elevation, parallel, sampling) -> None:
    cam = Camera.orbit(shape, azimuth, elevation, width=5, height=4, spacing=spacing, parallel=parallel)
    rs = cast_rays(cam, shape, spacing, step)
    full = brick_weights(rs, shape, spacing, shape, (0, 0, 0), sampling, step)
    parts = [
        brick_weights(rs, shape, spacing, brick, i, sampling, step)
        for i in itertools.product(*map(range, brick_grid(shape, brick)))
    ]
    split = sum(_dense(bw, shape, brick_bounds(shape, brick, bw.brick), rs.n_rays) for bw in parts)
    np.testing.assert_array_equal(split, _dense(full, shape, brick_bounds(shape, shape, (0, 0, 0)), rs.n_rays))
    touched = touched_bricks(rs, shape, spacing, brick, sampling, step)
    assert {bw.brick for bw in parts if bw.n_pairs} <= set(touched)
    vol = np.random.default_rng(0).random(shape)
    img = (split.reshape(rs.n_rays, -1) @ vol.reshape(-1)) * 10.0**full.exponent
    n = rs.n_samples
    img = np.divide(img, n, out=np.zeros_like(img), where=n > 0)
    ref = render_plain(vol, cam, sampling=sampling, step=step, spacing=spacing).reshape(-1)
    np.testing.assert_allclose(img, ref, rtol=0, atol=(1e-12 if sampling == "nearest" else 4e-3))


def test_per_brick_work_is_local(monkeypatch: pytest.MonkeyPatch) -> None:
    shape, brick = (40, 40, 40), (10, 10, 10)
    rs = cast_rays(Camera.orbit(shape, 30, 20, width=40, height=40), shape, (1, 1, 1), 1.0)
    generated: list[int] = []
    real = weights_mod.sample_positions

    def counting(rays, ray_idx, k, spacing, step):
        generated.append(len(ray_idx))
        return real(rays, ray_idx, k, spacing, step)

    monkeypatch.setattr(weights_mod, "sample_positions", counting)
    bw = brick_weights(rs, shape, (1, 1, 1), brick, (0, 3, 0), "trilinear", 1.0)
    assert bw.n_pairs > 0
    # One call clips all rays (k = 0 only), the rest generates samples near the brick only.
    assert sum(generated[1:]) < 0.05 * int(rs.n_samples.sum())


def test_apply_and_empty_brick() -> None:
    rs = cast_rays(Camera((2, 2, 9), (2, 2, 0), width=1, height=1, parallel=True), (5, 5, 5), (1, 1, 1), 1.0)
    bw = brick_weights(rs, (5, 5, 5), (1, 1, 1), 3, (1, 0, 0), "nearest", 1.0)
    assert bw.apply(np.arange(18.0).reshape(2, 3, 3)).tolist() == [8.0 + 17.0]  # local (2, 3, 3) edge brick
    empty = brick_weights(rs, (5, 5, 5), (1, 1, 1), 3, (0, 1, 1), "trilinear", 1.0)
    assert empty.n_pairs == 0 and empty.rays.size == 0 and empty.indptr.tolist() == [0]
    assert empty.apply(np.zeros((3, 2, 2))).shape == (0,)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(sampling="cubic"), "sampling"),
        (dict(brick=0), "brick"),
        (dict(brick=(2, 2)), "brick"),
        (dict(brick_index=(3, 0, 0)), "brick_index"),
        (dict(brick_index=(0, -1, 0)), "brick_index"),
        (dict(digits=-1), "digits"),
        (dict(digits=2.5), "digits"),
        (dict(step=0.0), "step"),
        (dict(rays="rays"), "rays"),
        (dict(shape=(4, 4)), "shape"),
        (dict(spacing=(1, 0, 1)), "spacing"),
    ],
)
def test_brick_weights_rejects(kwargs: dict, match: str) -> None:
    rs = cast_rays(Camera.orbit((4, 4, 4), width=3, height=3), (4, 4, 4), (1, 1, 1), 1.0)
    args = dict(
        rays=rs,
        shape=(4, 4, 4),
        spacing=(1, 1, 1),
        brick=2,
        brick_index=(0, 0, 0),
        sampling="nearest",
        step=1.0,
        digits=3,
    )
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        brick_weights(**args)


@pytest.mark.parametrize(
    "kwargs, match", [(dict(sampling="x"), "sampling"), (dict(brick=-2), "brick"), (dict(step=-1), "step")]
)
def test_touched_bricks_rejects(kwargs: dict, match: str) -> None:
    rs = cast_rays(Camera.orbit((4, 4, 4), width=3, height=3), (4, 4, 4), (1, 1, 1), 1.0)
    args = dict(rays=rs, shape=(4, 4, 4), spacing=(1, 1, 1), brick=2, sampling="nearest", step=1.0)
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        touched_bricks(**args)


def test_grid_helpers() -> None:
    assert brick_grid((7, 9, 11), (3, 4, 5)) == (3, 3, 3)
    assert brick_grid((64, 64, 64), 32) == (2, 2, 2)
    assert brick_bounds((7, 9, 11), (3, 4, 5), (2, 2, 2)) == ((6, 7), (8, 9), (10, 11))
