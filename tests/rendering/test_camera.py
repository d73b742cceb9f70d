"""Tests for hevr.rendering.geometry.camera.Camera (VTK conventions of API.md)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from hevr.errors import ParameterError
from hevr.rendering.geometry.camera import Camera


def test_basis_and_defaults() -> None:
    cam = Camera((0, 0, 10), (0, 0, 0))
    d, right, up = cam.basis()
    np.testing.assert_array_equal(d, [0, 0, -1])
    np.testing.assert_array_equal(right, [1, 0, 0])
    np.testing.assert_array_equal(up, [0, 1, 0])
    got = (cam.view_up, cam.view_angle, cam.width, cam.height, cam.parallel)
    assert got == ((0.0, 1.0, 0.0), 30.0, 150, 150, False)
    assert cam.parallel_scale == pytest.approx(10 * math.tan(math.radians(15)))


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("size", [(5, 3), (4, 4), (1, 1)])
def test_rays_layout(parallel: bool, size: tuple[int, int]) -> None:
    w, h = size
    cam = Camera((1, 2, 10), (1, 2, 0), width=w, height=h, parallel=parallel, parallel_scale=2.0)
    o, d = cam.rays()
    assert o.shape == d.shape == (w * h, 3) and o.dtype == d.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    # Pixel index row*W + col: columns go right (+x), rows go down (-y), row 0 at the top.
    if parallel:
        grid = o.reshape(h, w, 3)
        np.testing.assert_array_equal(d, np.tile([0.0, 0.0, -1.0], (w * h, 1)))
    else:
        grid = d.reshape(h, w, 3)
        np.testing.assert_array_equal(o, np.tile([1.0, 2.0, 10.0], (w * h, 1)))
    assert np.all(np.diff(grid[..., 0], axis=1) > 0) and np.all(np.diff(grid[..., 1], axis=0) < 0)


def test_parallel_origins_formula() -> None:
    cam = Camera((0, 0, 5), (0, 0, 0), width=4, height=2, parallel=True, parallel_scale=3.0)
    o, _ = cam.rays()
    aspect = 2.0
    u = ((np.arange(4) + 0.5) / 4 * 2 - 1) * aspect
    v = 1 - (np.arange(2) + 0.5) / 2 * 2
    np.testing.assert_allclose(o[:, 0], np.tile(3.0 * u, 2))
    np.testing.assert_allclose(o[:, 1], np.repeat(3.0 * v, 4))


def test_perspective_corner_angle() -> None:
    # The top edge of the image (v = 1) is view_angle/2 above the axis.
    cam = Camera((0, 0, 0), (0, 0, -1), view_angle=60, width=1, height=1)
    o, d = cam.rays()
    np.testing.assert_allclose(d[0], [0, 0, -1], atol=1e-15)
    big = Camera((0, 0, 0), (0, 0, -1), view_angle=60, width=1, height=1000)
    top = big.rays()[1][0]
    assert math.degrees(math.atan2(top[1], -top[2])) == pytest.approx(30 * (1 - 1 / 1000), rel=1e-3)


def test_identity_roundtrip_and_hash() -> None:
    cam = Camera(
        (1, 2, 3.5), (0, -1, 0), view_up=(0, 0, 1), view_angle=45, width=7, height=3, parallel=True, parallel_scale=2.5
    )
    data = cam.to_dict()
    text = json.dumps(data)
    back = Camera.from_dict(json.loads(text))
    assert back == cam and hash(back) == hash(cam) and back.key() == cam.key()
    assert isinstance(cam.key(), str) and len(cam.key()) == 64
    assert Camera((0, 0, 5), (0, 0, 0)).key() == Camera(np.array([0, 0, 5]), [0.0, -0.0, 0]).key()
    assert Camera((0, 0, 5), (0, 0, 0)).key() != Camera((0, 0, 5), (0, 0, 0), width=151).key()
    assert len({cam, back}) == 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.width = 3  # type: ignore[misc]


@pytest.mark.parametrize(
    "data, match",
    [
        ({"position": [0, 0, 1]}, "focal_point"),
        ({"position": [0, 0, 1], "focal_point": [0, 0, 0], "zoom": 2}, "zoom"),
        ([1, 2], "dict"),
    ],
)
def test_from_dict_rejects(data: object, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        Camera.from_dict(data)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(view_up=(0, 0, 2)), "view_up"),
        (dict(view_up=(0, 0, -1)), "view_up"),
        (dict(view_up=(0, 0, 0)), "view_up"),
        (dict(focal_point=(0, 0, 5)), "focal_point"),
        (dict(width=0), "width"),
        (dict(height=-3), "height"),
        (dict(width=1.5), "width"),
        (dict(width=True), "width"),
        (dict(view_angle=0), "view_angle"),
        (dict(view_angle=180), "view_angle"),
        (dict(view_angle=float("nan")), "view_angle"),
        (dict(parallel=True, parallel_scale=0.0), "parallel_scale"),
        (dict(parallel=True, parallel_scale=-1.0), "parallel_scale"),
        (dict(position=(0, 0)), "position"),
        (dict(position=(0, 0, float("inf"))), "position"),
        (dict(focal_point="origin"), "focal_point"),
        (dict(position=(True, 0, 5)), r"position: expected 3 finite numbers \(x, y, z\), got \(True, 0, 5\)"),
        (dict(view_up=np.array([False, True, False])), "view_up: expected 3 finite numbers"),
        (dict(focal_point=("0", "0", "0")), "focal_point: expected 3 finite numbers"),
        (dict(parallel="yes"), "parallel"),
    ],
)
def test_camera_rejects(kwargs: dict, match: str) -> None:
    args = dict(position=(0, 0, 5), focal_point=(0, 0, 0))
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        Camera(**args)


def test_orbit_default_pose() -> None:
    cam = Camera.orbit((5, 7, 9))
    assert cam.focal_point == (4.0, 3.0, 2.0)
    assert cam.position[:2] == (4.0, 3.0) and cam.position[2] > 2.0
    assert cam.view_up == (0.0, 1.0, 0.0)
    d, right, up = cam.basis()
    np.testing.assert_allclose(d, [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-15)


@pytest.mark.parametrize(
    "azimuth, elevation, side",
    [
        (90, 0, (1, 0, 0)),
        (-90, 0, (-1, 0, 0)),
        (180, 0, (0, 0, -1)),
        (0, 90, (0, 1, 0)),
        (0, -90, (0, -1, 0)),
        (45, 90, (0, 1, 0)),
        (270, -90, (0, -1, 0)),
    ],
)
def test_orbit_directions(azimuth: float, elevation: float, side: tuple) -> None:
    cam = Camera.orbit((4, 4, 4), azimuth=azimuth, elevation=elevation, width=8, height=8)
    offset = np.subtract(cam.position, cam.focal_point)
    np.testing.assert_allclose(offset / np.linalg.norm(offset), side, atol=1e-12)
    o, d = cam.rays()
    assert np.all(np.isfinite(d))
    # view_up is orthogonal to the view direction, so +-90 elevation is well defined.
    assert abs(np.dot(cam.basis()[0], cam.view_up)) < 1e-12


def _corners(shape: tuple, spacing: tuple) -> np.ndarray:
    ext = [(shape[2] - 1) * spacing[0], (shape[1] - 1) * spacing[1], (shape[0] - 1) * spacing[2]]
    return np.array(list(itertools.product(*[(0.0, e) for e in ext])))


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("size", [(150, 150), (200, 80), (60, 120)])
@pytest.mark.parametrize(
    "shape, spacing", [((10, 20, 30), (1, 1, 1)), ((5, 64, 64), (0.5, 0.5, 3.0)), ((1, 1, 1), (1, 1, 1))]
)
@pytest.mark.parametrize("angles", [(0, 0), (30, 20), (-120, 75)])
def test_orbit_frames_the_box(parallel: bool, size: tuple, shape: tuple, spacing: tuple, angles: tuple) -> None:
    w, h = size
    cam = Camera.orbit(shape, *angles, width=w, height=h, spacing=spacing, parallel=parallel)
    d, right, up = cam.basis()
    rel = _corners(shape, spacing) - np.asarray(cam.position)
    x, y, z = rel @ right, rel @ up, rel @ d
    assert np.all(z > 0)  # the whole box is in front of the camera
    if parallel:
        half_w, half_h = np.abs(x).max(), np.abs(y).max()
        scale = cam.parallel_scale
    else:
        half_w, half_h = np.abs(x / z).max(), np.abs(y / z).max()
        scale = math.tan(math.radians(cam.view_angle) / 2)
    assert half_h <= scale and half_w <= scale * w / h
    # ... and not absurdly small: the box fills at least a third of the narrower side.
    if shape != (1, 1, 1):
        assert max(half_w / (scale * w / h), half_h / scale) > 1 / 3


def test_orbit_with_volume_object_and_overrides() -> None:
    ev = SimpleNamespace(shape=(5, 7, 9), spacing=(2.0, 1.0, 0.5))
    cam = Camera.orbit(ev, distance=50.0, width=10, height=20, view_angle=20)
    assert cam.focal_point == (8.0, 3.0, 1.0)
    assert np.linalg.norm(np.subtract(cam.position, cam.focal_point)) == pytest.approx(50.0)
    assert (cam.width, cam.height, cam.view_angle) == (10, 20, 20.0)
    cam2 = Camera.orbit(ev, spacing=(1, 1, 1))  # explicit spacing wins
    assert cam2.focal_point == (4.0, 3.0, 2.0)
    cam3 = Camera.orbit((5, 7, 9), parallel=True)
    assert cam3.parallel and cam3.parallel_scale > 0


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        (((5, 7),), {}, "ev_or_shape"),
        (((5, 0, 7),), {}, "ev_or_shape"),
        ((3,), {}, "ev_or_shape"),
        (((5, 5, 5),), dict(distance=0.0), "distance"),
        (((5, 5, 5),), dict(spacing=(1, 0, 1)), "spacing"),
        (((5, 5, 5),), dict(azimuth=float("nan")), "azimuth"),
        (((5, 5, 5),), dict(view_angle=200), "view_angle"),
        (((5, 5, 5),), dict(width=0), "width"),
    ],
)
def test_orbit_rejects(args: tuple, kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        Camera.orbit(*args, **kwargs)


@pytest.mark.parametrize(
    "pixels, match",
    [
        ([0.5], "expected integer pixel indices, got float64"),
        (["a"], "expected integer pixel indices"),
        ([-1], r"expected indices in \[0, 6\), got -1"),
        ([6], r"expected indices in \[0, 6\), got 6"),
    ],
)
def test_rays_of_bad_pixels_are_refused(pixels, match):
    cam = Camera((0, 0, 5), (0, 0, 0), width=3, height=2)
    with pytest.raises(ParameterError, match=match):
        cam.rays(pixels)
    assert cam.rays([])[0].shape == (0, 3)
