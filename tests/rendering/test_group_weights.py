"""Tests for hevr.rendering.geometry.group_weights: many bricks' nearest weights in one pass, checked
pair for pair against the per-brick reference :func:`hevr.rendering.geometry.weights.brick_weights`."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from array_api_compat import array_namespace
from hypothesis import given, settings
from hypothesis import strategies as st

from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.group_weights import nearest_group_weights
from hevr.rendering.geometry.plane import Plane
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import brick_grid, brick_weights


def _pairs(bw) -> list[tuple[int, int, int]]:
    """(global ray, voxel, weight) of every pair, sorted: the weights without their order."""
    rows = np.repeat(bw.rays, np.diff(bw.indptr))
    return sorted(zip(rows.tolist(), bw.voxels.tolist(), bw.weights.tolist()))


def _check(rays, shape, spacing, brick, step, indices) -> int:
    got = nearest_group_weights(rays, shape, spacing, brick, indices, step)
    assert sorted(got) == sorted(indices)
    pairs = 0
    for idx in indices:
        ref = brick_weights(rays, shape, spacing, brick, idx, "nearest", step)
        g = got[idx]
        assert _pairs(g) == _pairs(ref), idx
        assert g.rays.tolist() == ref.rays.tolist()  # rows: the same rays, ascending
        assert g.exponent == 0 and np.all(np.diff(g.indptr) > 0)
        pairs += ref.n_pairs
    return pairs


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-180, 180),
    st.floats(-80, 80),
    st.sampled_from([(9, 7, 8), (5, 11, 6)]),
    st.sampled_from([3, (4, 2, 5), 16]),
    st.sampled_from([0.5, 1.0, 1.7]),
    st.booleans(),
    st.integers(0, 2**16),
)
def test_matches_brick_weights(az, el, shape, brick, step, parallel, seed):
    spacing = (1.0, 0.8, 1.3)
    cam = Camera.orbit(shape, az, el, width=13, height=11, spacing=spacing, parallel=parallel)
    rays = cast_rays(cam, shape, spacing, step)
    grid = brick_grid(shape, brick)
    every = list(itertools.product(*(range(g) for g in grid)))
    rng = np.random.default_rng(seed)
    some = [every[i] for i in sorted(rng.choice(len(every), size=max(1, len(every) // 2), replace=False))]
    _check(rays, shape, spacing, brick, step, every)
    _check(rays, shape, spacing, brick, step, some)


def test_footprint_subset_and_planes():
    """A subset of the image's rays (pixel ids) and a plane's rays (slices) give the same pairs."""
    shape, spacing, brick = (10, 9, 8), (1.0, 1.0, 2.0), (4, 4, 3)
    every = list(itertools.product(*(range(g) for g in brick_grid(shape, brick))))
    cam = Camera.orbit(shape, 30, 20, width=16, height=12, spacing=spacing)
    rays = cast_rays(cam, shape, spacing, 1.0, pixels=np.arange(40, 150, 3))
    assert _check(rays, shape, spacing, brick, 1.0, every) > 0
    for plane in (Plane.axial(shape, 4.3, width=9, height=10), Plane.coronal(shape, 2, slab=3)):
        prays = cast_rays(plane, shape, spacing, 1.0)
        assert _check(prays, shape, spacing, brick, 1.0, every) > 0


def test_no_ray_hits():
    shape = (6, 6, 6)
    cam = Camera((100, 100, 100), (200, 200, 200), width=4, height=3)
    rays = cast_rays(cam, shape, (1, 1, 1), 1.0)
    got = nearest_group_weights(rays, shape, (1, 1, 1), 3, [(0, 0, 0), (1, 1, 1)], 1.0)
    assert all(w.n_pairs == 0 and w.rays.size == 0 and w.indptr.tolist() == [0] for w in got.values())


@pytest.mark.parametrize("brick", [2, (3, 1, 2)])
def test_tiny_bricks_and_one_voxel_rows(brick):
    shape = (4, 3, 5)
    cam = Camera.orbit(shape, 10, -35, width=9, height=7, spacing=(1, 1, 1))
    every = list(itertools.product(*(range(g) for g in brick_grid(shape, brick))))
    assert _check(cast_rays(cam, shape, (1, 1, 1), 0.3), shape, (1, 1, 1), brick, 0.3, every) > 0


# -- the same geometry under a second array namespace (issue 27, item 2) ------------------------------
@pytest.mark.parametrize("view", ["camera", "parallel", "plane"])
def test_geometry_is_namespace_generic(view):
    """Rays -> samples -> nearest weights run unchanged on ``array_api_strict`` arrays (the
    strictest implementation of the array API standard, standing in for CuPy on a GPU worker)
    and give the numpy result bit for bit."""
    xps = pytest.importorskip("array_api_strict")
    from hevr.rendering.geometry.group_weights import nearest_group_rows

    shape, spacing, brick = (11, 9, 10), (1.0, 0.9, 1.2), (4, 3, 5)
    if view == "plane":
        cam = Plane.coronal(shape, 4.5, slab=3, width=12, height=14)
    else:
        cam = Camera.orbit(shape, 33, 21, width=17, height=13, spacing=spacing, parallel=view == "parallel")
    rays = cast_rays(cam, shape, spacing, 0.8 if view != "plane" else 1.0, pixels=np.arange(3, 150, 2))
    every = list(itertools.product(*(range(g) for g in brick_grid(shape, brick))))
    some = every[5:17]
    for indices in (every, some):
        ref = nearest_group_rows(rays, shape, spacing, brick, indices, 0.8 if view != "plane" else 1.0)
        got = nearest_group_rows(
            rays.to_namespace(xps), shape, spacing, brick, indices, 0.8 if view != "plane" else 1.0
        )
        assert ref.indptr[-1] > 0
        for name in ("rays", "indptr", "brick", "local", "weights"):
            a, b = getattr(ref, name), getattr(got, name)
            assert array_namespace(b) is xps and not isinstance(b, np.ndarray), name
            assert np.array_equal(np.from_dlpack(b), a) and np.from_dlpack(b).dtype == a.dtype, name
