"""Dragging on hevr.Viewer's image, headlessly: the front end's messages (``{"type": "camera",
"dx", "dy", "wheel", "release"}``, hevr/viewer/drag.py) are handed to the image widget as the kernel
would hand them, and the camera sliders, the frames rendered (preview level during a drag, the
full frame on release) and the answers to the front end are checked. Every frame is compared
with render_plain within error_bound at its level. The browser drags in
tests/test_viewer_browser.py."""

from __future__ import annotations

import io
import logging
import sys
import time

import numpy as np
import pytest
from PIL import Image

import hevr
from hevr.viewer import Viewer
from hevr.viewer.drag import DEGREES_PER_WIDTH, WHEEL_PIXELS_PER_DOUBLING

pytest.importorskip("ipywidgets")  # the notebook extra; installed with the test extra
pytest.importorskip("anywidget")


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256):
    """A tiny multi-brick store with a pyramid level, and one without."""
    _pub, priv = keypair256
    vol = hevr.phantom(8)
    d = tmp_path_factory.mktemp("drag")
    flat = hevr.encrypt_volume(vol, d / "flat.zarr", priv, brick=4, vector_dims=3, progress=False)
    pyr = hevr.encrypt_volume(vol, d / "pyr.zarr", priv, brick=4, vector_dims=3, progress=False)
    pyr = hevr.build_pyramid(pyr, 1, progress=False)
    return pyr, flat, priv, vol


def _viewer(ev, priv, vol, **kw) -> Viewer:
    hevr.clear_cache()
    v = Viewer(ev, priv, volume=vol, width=10, height=8, mode="emphasize", **kw)
    v.answers = []
    v.image.send = lambda content, buffers=None: v.answers.append(content)  # what goes back to the browser
    return v


def _message(v: Viewer, dx: float = 0.0, dy: float = 0.0, wheel: float = 0.0, release: bool = False, **extra) -> None:
    """What the front end sends, delivered as the kernel delivers a widget's custom message."""
    v.image._handle_custom_msg({"type": "camera", "dx": dx, "dy": dy, "wheel": wheel, "release": release, **extra}, [])


def _right(v: Viewer, entry: dict) -> None:
    """The entry is the frame on show, of the sliders' camera at its level, and the decrypted
    frame is within error_bound of render_plain, pixel by pixel; the PNG has the viewer's size."""
    level = entry["level"]
    cam = v.camera(level)
    assert entry["camera"] == cam.to_dict()  # the sliders are the camera that was rendered
    assert entry is v.history[-1] and entry["error"] <= entry["bound"]
    kw = v.request()
    ref = hevr.render_plain(
        v.volume, cam, value_range=v.ev.value_range, vector_dims=v.ev.vector_dims, level=level, **kw
    )
    bound = hevr.error_bound(v.ev, cam, level=level or None, **kw)
    assert v.frame.image.shape == (cam.height, cam.width) == ref.shape
    assert (np.abs(v.frame.image - ref) <= bound).all()
    assert Image.open(io.BytesIO(bytes(v.image.value))).size == v.size


def test_a_drag_orbits_with_previews_and_ends_with_the_full_frame(stores):
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=None)
    assert v.preview == 1 and v.image.width == 256 and v.image.height == 256
    assert (v.azimuth.value, v.elevation.value) == (30.0, 20.0)
    n = len(v.history)
    _message(v, dx=0.1, dy=-0.05)  # right and up: the volume turns with the pointer
    assert v.azimuth.value == pytest.approx(30.0 - DEGREES_PER_WIDTH * 0.1)
    assert v.elevation.value == pytest.approx(20.0 - DEGREES_PER_WIDTH * 0.05)
    assert len(v.history) == n + 1 and v.history[-1]["level"] == 1 and v.history[-1]["map_tasks"] > 0
    assert v.history[-1]["camera"]["width"] == 5 and "preview at pyramid level 1" in v.status.value
    _right(v, v.history[-1])
    assert v._timer is None  # no settle timer during a drag: the full frame waits for the release
    _message(v, dx=-0.05, dy=0.2)
    assert v.history[-1]["level"] == 1 and len(v.history) == n + 2
    assert v.azimuth.value == pytest.approx(30.0 - DEGREES_PER_WIDTH * 0.05)
    assert v.elevation.value == pytest.approx(20.0 + DEGREES_PER_WIDTH * 0.15)
    assert v.azimuth.value == 21.0 and v.elevation.value == 47.0  # on the sliders' 1° steps
    _right(v, v.history[-1])
    _message(v, dx=0.02, release=True)  # the last movement and the release: the full frame of it, no preview
    last = v.history[-1]
    assert len(v.history) == n + 3 and last["level"] == 0 and last["camera"]["width"] == 10
    assert v.azimuth.value == round(30.0 - DEGREES_PER_WIDTH * 0.07) == 17.0  # 17.4 on the 1° step
    _right(v, last)
    assert v.answers == [{"type": "done"}] * 3 and v.orbit.messages == 3
    _message(v, release=True)  # a click: nothing pending, nothing rendered, still answered
    assert len(v.history) == n + 3 and len(v.answers) == 4
    m = len(v.history)
    v.elevation.value = v.elevation.value + 1.4e-14  # a browser's slider sends the value back, recomputed:
    assert len(v.history) == m  # not a move, no render
    _message(v, dx=-0.002, release=True)  # and the drag's exact position is kept: 17.4 + 0.36 -> 18
    assert v.azimuth.value == 18.0 and len(v.history) == m + 1
    _right(v, v.history[-1])
    # the same position set on the sliders gives the same request and camera (one source of truth)
    w = _viewer(pyr, priv, vol, settle=None, show=False)
    with w.hold():
        w.azimuth.value, w.elevation.value = v.azimuth.value, v.elevation.value
    assert w.history[-1]["camera"] == v.history[-1]["camera"]
    assert w.history[-1]["request"] == v.history[-1]["request"]


def test_slow_drags_add_up_on_the_slider_steps(stores):
    """Movements smaller than a slider step render nothing but are kept: ten of 0.18° turn the
    camera by 2° (on the steps: 30 -> 29 -> 28), and a slider moved by hand starts afresh."""
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=None)
    n = len(v.history)
    seen = []
    for _ in range(10):
        _message(v, dx=0.001)  # 0.18° each
        seen.append(v.azimuth.value)
    assert seen == [30.0, 30.0, 29.0, 29.0, 29.0, 29.0, 29.0, 29.0, 28.0, 28.0]  # 29.64 -> 30, 29.46 -> 29, ...
    assert len(v.history) == n + 2 and [e["level"] for e in v.history[n:]] == [1, 1]
    _right(v, v.history[-1])
    with v.hold():
        v.azimuth.value = 100.0  # the slider, by hand
    _message(v, dx=0.001, dy=0.001)  # 99.82 -> 100, 20.18 -> 20: no change, no render
    assert (v.azimuth.value, v.elevation.value) == (100.0, 20.0) and v.history[-1]["level"] == 0
    _message(v, dx=0.002, release=True)  # 99.46 -> 99: the full frame
    assert v.azimuth.value == 99.0 and v.history[-1]["level"] == 0 and v.history[-1]["camera"]["width"] == 10
    _right(v, v.history[-1])


def test_pauses_in_a_drag_and_a_release_after_previews(stores):
    """A release with no movement after previews renders the full frame (the previews pending)."""
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=0.05)
    _message(v, dy=0.1)
    assert v.history[-1]["level"] == 1
    time.sleep(0.3)  # longer than `settle`: a drag does not start the timer
    assert v.history[-1]["level"] == 1
    _message(v, release=True)
    assert v.history[-1]["level"] == 0 and v.settle() is None
    _right(v, v.history[-1])


def test_limits_like_the_sliders(stores):
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=None)
    _message(v, dy=2.0)  # elevation stops at the slider's end
    assert v.elevation.value == v.elevation.max == 89.0
    n = len(v.history)
    _message(v, dy=0.5)  # already there: nothing moves, nothing renders
    assert len(v.history) == n and len(v.answers) == 2
    _message(v, dx=-1.0)  # azimuth wraps around: 30 + 180 = 210 -> -150
    assert v.azimuth.value == pytest.approx(-150.0)
    _message(v, dx=-0.5, release=True)  # -150 + 90 = -60
    assert v.azimuth.value == pytest.approx(-60.0) and v.history[-1]["level"] == 0
    _right(v, v.history[-1])
    unwrapped = -60.0
    for dx in (7.3, -11.9):  # any number of turns stays within the slider's range, at the same angle
        _message(v, dx=dx)
        unwrapped -= DEGREES_PER_WIDTH * dx
        assert v.azimuth.min <= v.azimuth.value <= v.azimuth.max
        assert abs((v.azimuth.value - unwrapped + 180.0) % 360.0 - 180.0) < 1e-9


def test_the_wheel_zooms(stores):
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=None)
    _message(v, wheel=-WHEEL_PIXELS_PER_DOUBLING)  # towards the volume: half the view angle
    assert v.view_angle.value == pytest.approx(15.0) and v.history[-1]["level"] == 1
    assert v.history[-1]["camera"]["view_angle"] == pytest.approx(15.0)
    _right(v, v.history[-1])
    full = v.settle()  # a wheel turn has no release: the viewer's settle (its timer in a notebook)
    assert full["level"] == 0
    _right(v, full)
    v.orbit.zoom(10 * WHEEL_PIXELS_PER_DOUBLING)  # clamped at the slider's widest
    assert v.view_angle.value == v.view_angle.max == 90.0
    n = len(v.history)
    assert v.orbit.zoom(100.0) is None and len(v.history) == n  # already at the end
    _message(v, wheel=1e9)  # absurd wheel values are clamped, not an overflow
    assert v.view_angle.value == 90.0 and v.answers[-1] == {"type": "done"}
    timed = _viewer(pyr, priv, vol, settle=0.05)
    timed.orbit.zoom(-200.0)
    assert timed.history[-1]["level"] == 1
    deadline = time.time() + 20
    while timed.history[-1]["level"] != 0 and time.time() < deadline:
        time.sleep(0.05)
    assert timed.history[-1]["level"] == 0  # the timer rendered the full frame
    assert timed.view_angle.value == round(30.0 * 2 ** (-200.0 / WHEEL_PIXELS_PER_DOUBLING)) == 23.0  # 22.7


def test_without_a_pyramid_each_message_renders_the_full_frame(stores):
    _pyr, flat, priv, vol = stores
    v = _viewer(flat, priv, vol, settle=None)
    assert v.preview == 0
    n = len(v.history)
    _message(v, dx=0.25)
    assert len(v.history) == n + 1 and v.history[-1]["level"] == 0
    _right(v, v.history[-1])
    _message(v, release=True)  # already the full frame: nothing more
    assert len(v.history) == n + 1
    _message(v, dx=0.01, dy=0.01, release=True)
    assert len(v.history) == n + 2 and v.history[-1]["level"] == 0
    _right(v, v.history[-1])


def test_a_held_viewer_renders_once_at_the_end(stores):
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=None)
    n = len(v.history)
    with v.hold():
        assert v.orbit.drag(0.1, 0.0) is None and v.orbit.drag(0.0, 0.0, release=True) is None
    assert len(v.history) == n + 1 and v.history[-1]["level"] == 0
    assert v.azimuth.value == pytest.approx(12.0)
    _right(v, v.history[-1])


def test_bad_messages_are_ignored_and_answered(stores, caplog):
    pyr, _flat, priv, vol = stores
    v = _viewer(pyr, priv, vol, settle=None)
    n = len(v.history)
    with caplog.at_level(logging.WARNING, logger="hevr.viewer.drag"):
        _message(v, dx="left")
        _message(v, dx=float("nan"))
        _message(v, dy=True)
        v.image._handle_custom_msg({"type": "click"}, [])
        v.image._handle_custom_msg("camera", [])
    assert len(v.history) == n and (v.azimuth.value, v.elevation.value) == (30.0, 20.0)
    assert v.answers == [{"type": "done"}] * 5  # the front end is never left waiting
    text = caplog.text
    assert "dx: expected a finite number, got 'left'" in text and "dx: expected a finite number, got nan" in text
    assert "dy: expected a finite number, got True" in text and "ignored a message from the front end" in text


def test_without_anywidget_the_viewer_names_it(stores, monkeypatch):
    pyr, _flat, priv, _vol = stores
    monkeypatch.setitem(sys.modules, "anywidget", None)  # what an environment without it gives: ImportError
    with pytest.raises(
        hevr.MissingDependencyError,
        match=r"expected ipywidgets and anywidget \(pip install "
        r"'hevr\[notebook\]'\), got an environment without anywidget",
    ):
        Viewer(pyr, priv, show=False)
