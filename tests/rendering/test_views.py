"""Anatomical camera presets (``Camera.orbit(view=...)``) in the RAS+ patient frame.

The phantom is a dark cube with a bright blob at the patient's right-anterior-superior corner
(high x, y and z index); each view must show it where a radiologist expects it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import hevr
from hevr import Camera
from hevr.rendering.geometry.views import VIEWS, view_axes

N = 12
SIZE = 24


@pytest.fixture(scope="module")
def blob():
    vol = np.zeros((N, N, N), np.uint8)  # (z, y, x)
    vol[8:11, 8:11, 8:11] = 255  # superior, anterior, right
    return vol


def _render(vol, view, **kw):
    cam = Camera.orbit(vol.shape, view=view, width=SIZE, height=SIZE, parallel=True, **kw)
    return hevr.render_plain(vol, cam, mode="xray")


def _where(img) -> tuple[str, str]:
    r, c = np.unravel_index(int(np.argmax(img)), img.shape)
    assert img[r, c] > 0
    return ("top" if r < SIZE / 2 else "bottom"), ("left" if c < SIZE / 2 else "right")


# The blob (patient's right, anterior, superior) seen from each side:
EXPECTED = {
    "anterior": ("top", "left"),  # facing the patient: their right on the image's left
    "posterior": ("top", "right"),  # from behind: their right on the image's right
    "left": ("top", "left"),  # from the left side: anterior on the image's left
    "right": ("top", "right"),  # from the right side: anterior on the image's right
    "superior": ("top", "right"),  # from above, anterior up: their right on the image's right
    "inferior": ("top", "left"),  # from the feet, anterior up (radiological axial): right on the left
}


def test_views_constant():
    assert Camera.VIEWS == VIEWS == ("anterior", "posterior", "left", "right", "superior", "inferior")
    assert hevr.VIEWS == VIEWS
    assert set(EXPECTED) == set(VIEWS)


@pytest.mark.parametrize("view", VIEWS)
def test_blob_appears_where_radiology_puts_it(blob, view):
    assert _where(_render(blob, view)) == EXPECTED[view]


@pytest.mark.parametrize("view", VIEWS)
def test_every_preset_is_a_valid_camera(view):
    cam = Camera.orbit((N, N + 2, N + 4), view=view, width=8, height=6, spacing=(0.5, 1.0, 2.0))
    assert Camera.from_dict(cam.to_dict()) == cam
    d, right, up = cam.basis()
    back, want_up = view_axes(view)
    assert np.allclose(d, -back) and np.allclose(up, want_up)
    assert np.allclose(np.cross(right, up), -d)  # a right-handed image frame
    # the camera looks at the centre from the named side
    centre = np.array(cam.focal_point)
    assert np.allclose(centre, [(N + 3) * 0.5 / 2, (N + 1) * 1.0 / 2, (N - 1) * 2.0 / 2])
    assert float(np.dot(np.subtract(cam.position, centre), back)) > 0


@pytest.mark.parametrize("a, b", [("anterior", "posterior"), ("left", "right"), ("superior", "inferior")])
def test_opposite_views_are_mirror_images(blob, a, b):
    sym = np.maximum(blob, 0)
    sym[2:5, 3:6, 6:9] = 100  # a second, dimmer blob: not symmetric either
    ia, ib = _render(sym, a), _render(sym, b)
    assert ia.max() > 0
    assert np.allclose(ia, ib[:, ::-1], atol=1e-9)
    assert not np.allclose(ia, ib, atol=1e-3)


@pytest.mark.parametrize(
    "view, azimuth, elevation, same_place_as",
    [
        ("anterior", 90, 0, "left"),
        ("anterior", -90, 0, "right"),
        ("anterior", 180, 0, "posterior"),
        ("right", 90, 0, "anterior"),
        ("left", 90, 0, "posterior"),
        ("anterior", 0, 90, "superior"),
        ("posterior", 0, -90, "inferior"),
        ("superior", 0, 90, "anterior"),
        ("inferior", 90, 0, "left"),
    ],
)
def test_azimuth_and_elevation_are_relative_to_the_view(view, azimuth, elevation, same_place_as):
    shape = (10, 14, 18)
    cam = Camera.orbit(shape, azimuth=azimuth, elevation=elevation, view=view)
    ref = Camera.orbit(shape, view=same_place_as)
    assert np.allclose(cam.position, ref.position, atol=1e-9)
    if elevation == 0 and np.allclose(view_axes(view)[1], view_axes(same_place_as)[1]):
        # a turn about the up axis keeps the image's up
        assert np.allclose(cam.view_up, ref.view_up, atol=1e-12)


def test_positive_azimuth_moves_towards_the_image_right():
    for view in (None,) + VIEWS:
        cam0 = Camera.orbit((8, 8, 8), view=view)
        cam1 = Camera.orbit((8, 8, 8), azimuth=10, view=view)
        _, right, _ = cam0.basis()
        assert float(np.dot(np.subtract(cam1.position, cam0.position), right)) > 0, view


def test_no_view_is_the_plain_orbit():
    for az, el in [(0, 0), (30, 20), (-120, 75)]:
        cam = Camera.orbit((10, 20, 30), azimuth=az, elevation=el)
        dist = np.linalg.norm(np.subtract(cam.position, cam.focal_point))
        a, e = math.radians(az), math.radians(el)
        want = np.add(
            cam.focal_point, dist * np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
        )
        assert np.allclose(cam.position, want)
    assert Camera.orbit((4, 5, 6), view=None) == Camera.orbit((4, 5, 6))


@pytest.mark.parametrize("bad", ["front", "Anterior", "", 3])
def test_unknown_view_lists_the_choices(bad):
    with pytest.raises(
        hevr.ParameterError, match="^view: expected one of anterior, posterior, left, right, superior, inferior, got "
    ):
        Camera.orbit((4, 4, 4), view=bad)
