"""Tests for hevr.rendering.geometry.rays: ray/box clipping and the shared sample-position helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hevr.errors import ParameterError
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.rays import (
    RaySet,
    cast_rays,
    check_shape,
    check_spacing,
    corner_index,
    expand_samples,
    nearest_voxels,
    sample_positions,
    trilinear_corners,
)


def column_camera(shape: tuple, spacing: tuple, parallel_scale_pad: float = 0.0) -> Camera:
    """Parallel camera looking down -z whose pixel centres sit on the voxel columns (sx == sy)."""
    nz, ny, nx = shape
    sx, sy, sz = spacing
    assert sx == sy
    centre = ((nx - 1) * sx / 2, (ny - 1) * sy / 2)
    return Camera(
        (*centre, (nz - 1) * sz + 10.0),
        (*centre, 0.0),
        width=nx,
        height=ny,
        parallel=True,
        parallel_scale=ny * sy / 2 + parallel_scale_pad,
    )


@pytest.mark.parametrize(
    "shape, spacing", [((5, 7, 9), (1, 1, 1)), ((4, 3, 6), (0.5, 0.5, 2.5)), ((1, 1, 1), (1, 1, 1))]
)
def test_rays_on_faces_are_inside(shape: tuple, spacing: tuple) -> None:
    cam = column_camera(shape, spacing)
    rs = cast_rays(cam, shape, spacing, spacing[2])
    assert isinstance(rs, RaySet) and rs.n_rays == shape[1] * shape[2]
    # Border pixel centres lie exactly on the x/y faces; all of them hit with nz samples.
    np.testing.assert_array_equal(rs.n_samples, shape[0])
    assert rs.n_samples.dtype == np.int64
    np.testing.assert_allclose(rs.t_exit - rs.t_enter, (shape[0] - 1) * spacing[2], atol=1e-12)


def test_misses_and_sample_count_formula() -> None:
    shape, spacing = (5, 7, 9), (1.0, 1.0, 1.0)
    cam = column_camera(shape, spacing, parallel_scale_pad=2.0)  # pads the image around the box
    for step in (1.0, 0.3, 0.7, 2.5):
        rs = cast_rays(cam, shape, spacing, step)
        hit = rs.n_samples > 0
        assert 0 < hit.sum() < rs.n_rays
        assert np.all(rs.t_enter[~hit] == 0) and np.all(rs.t_exit[~hit] == 0)
        expected = np.floor((rs.t_exit - rs.t_enter) / step + 1e-9).astype(np.int64) + 1
        np.testing.assert_array_equal(rs.n_samples[hit], expected[hit])
        last = rs.t_enter + (rs.n_samples - 1) * step
        assert np.all(last[hit] <= rs.t_exit[hit] + 1e-9 * step)
        assert np.all(last[hit] + step > rs.t_exit[hit] + 1e-9 * step)


def test_zero_direction_components_and_outside_slab() -> None:
    shape = (3, 3, 3)
    # Axis-aligned rays (two exactly zero components), some outside the x slab.
    cam = Camera((1, 1, 5), (1, 1, 0), width=5, height=1, parallel=True, parallel_scale=0.5)
    rs = cast_rays(cam, shape, (1, 1, 1), 1.0)
    np.testing.assert_array_equal(rs.n_samples, [0, 3, 3, 3, 0])  # x = -1, 0, 1, 2, 3


@pytest.mark.parametrize("axis_len", [1])
def test_degenerate_one_voxel_axes(axis_len: int) -> None:
    shape = (axis_len, 5, 5)  # a single z slice: the box is the plane z = 0
    face_on = cast_rays(
        Camera((2, 2, 3), (2, 2, 0), width=5, height=5, parallel=True, parallel_scale=2.5), shape, (1, 1, 1), 1.0
    )
    np.testing.assert_array_equal(face_on.n_samples, 1)
    edge_on = cast_rays(
        Camera((9, 2, 0), (0, 2, 0), width=5, height=3, parallel=True, parallel_scale=1.5), shape, (1, 1, 1), 1.0
    )
    # Rows at y = 3, 2, 1 and columns at z = -2..2: only the z = 0 column lies in the plane.
    n = edge_on.n_samples.reshape(3, 5)
    np.testing.assert_array_equal(n[:, 2], 5)
    assert n[:, [0, 1, 3, 4]].sum() == 0
    oblique = cast_rays(Camera((2, 2, 3), (1, 1, 0), width=3, height=3), shape, (1, 1, 1), 1.0)
    assert set(oblique.n_samples.tolist()) <= {0, 1} and oblique.n_samples.sum() > 0


def test_behind_camera_and_inside_box() -> None:
    shape = (5, 5, 5)
    away = cast_rays(Camera((2, 2, 10), (2, 2, 20), width=3, height=3), shape, (1, 1, 1), 1.0)
    assert away.n_samples.sum() == 0
    inside = cast_rays(Camera((2, 2, 2), (2, 2, 0), width=1, height=1), shape, (1, 1, 1), 1.0)
    assert inside.t_enter[0] == 0.0 and inside.t_exit[0] == pytest.approx(2.0)
    assert inside.n_samples[0] == 3


@pytest.mark.parametrize("step", [0, -1.0, float("nan"), float("inf"), True, "1", None])
def test_bad_step(step: object) -> None:
    with pytest.raises(ParameterError, match="step"):
        cast_rays(Camera((0, 0, 5), (0, 0, 0)), (2, 2, 2), (1, 1, 1), step)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(shape=(2, 2)), "shape"),
        (dict(shape=(2, 0, 2)), "shape"),
        (dict(shape=(2, 2.0, 2)), "shape"),
        (dict(spacing=(1, 1)), "spacing"),
        (dict(spacing=(1, -1, 1)), "spacing"),
        (dict(spacing="x"), "spacing"),
        (dict(camera="cam"), "camera"),
    ],
)
def test_cast_rays_rejects(kwargs: dict, match: str) -> None:
    args = dict(camera=Camera((0, 0, 5), (0, 0, 0)), shape=(2, 2, 2), spacing=(1, 1, 1), step=1.0)
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        cast_rays(**args)


def test_check_helpers() -> None:
    assert check_shape(np.array([1, 2, 3])) == (1, 2, 3)
    assert check_spacing([1, 2, 3]) == (1.0, 2.0, 3.0)


def test_sample_positions_are_batch_invariant() -> None:
    shape, spacing, step = (6, 7, 8), (0.9, 1.1, 1.7), 0.37
    rs = cast_rays(Camera.orbit(shape, 31, 17, width=9, height=7, spacing=spacing), shape, spacing, step)
    hits = np.flatnonzero(rs.n_samples)
    ray_idx, k = expand_samples(hits, np.zeros_like(hits), rs.n_samples[hits])
    p_all = sample_positions(rs, ray_idx, k, spacing, step)
    sub = np.arange(0, ray_idx.size, 7)[::-1]  # a different subset in a different order
    np.testing.assert_array_equal(sample_positions(rs, ray_idx[sub], k[sub], spacing, step), p_all[sub])
    # Index space: p = world / spacing, and every sample is in the box (up to tolerance).
    upper = np.array([shape[2] - 1, shape[1] - 1, shape[0] - 1])
    assert np.all(p_all > -1e-9) and np.all(p_all < upper + 1e-9)
    world = rs.origins[ray_idx] + (rs.t_enter[ray_idx] + k * step)[:, None] * rs.directions[ray_idx]
    np.testing.assert_array_equal(p_all, world / np.asarray(spacing))


def test_nearest_voxels_round_half_up_and_clamp() -> None:
    p = np.array([[0.5, 1.5, 2.5], [0.4999, -0.5, -3.0], [9.0, 1.49, 2.51]])
    np.testing.assert_array_equal(nearest_voxels(p, (4, 3, 2)), [[1, 2, 3], [0, 0, 0], [1, 1, 3]])


def test_trilinear_corners() -> None:
    rng = np.random.default_rng(3)
    shape = (4, 5, 6)
    p = rng.uniform(-1e-12, 1, (200, 3)) * np.array([5, 4, 3])
    lo, hi, w = trilinear_corners(p, shape)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-15)
    assert np.all(w >= 0) and np.all(lo >= 0) and np.all(hi <= [5, 4, 3])
    interp = sum(w[:, c] * (corner_index(lo, hi, c) @ [1.0, 10.0, 100.0]) for c in range(8))
    # Trilinear interpolation reproduces linear functions exactly (inside the box).
    np.testing.assert_allclose(interp, np.clip(p, 0, None) @ [1.0, 10.0, 100.0], atol=1e-9)
    lo, hi, w = trilinear_corners(np.array([[5.0, 4.0, 3.0]]), shape)  # far corner: clamped
    np.testing.assert_array_equal(hi, [[5, 4, 3]])
    assert w[0, 0] == 1.0 and math.isclose(w.sum(), 1.0)


def test_expand_samples() -> None:
    r, k = expand_samples(np.array([3, 5, 6]), np.array([0, 2, 1]), np.array([2, 3, 0]))
    assert r.tolist() == [3, 3, 5, 5, 5] and k.tolist() == [0, 1, 2, 3, 4]
    r, k = expand_samples(np.array([], dtype=np.int64), np.array([], dtype=np.int64), np.array([], dtype=np.int64))
    assert r.size == k.size == 0
