"""The viewer's image as a drag surface: orbit by dragging, zoom with the wheel.

ipywidgets' ``Image`` has no pointer events, so the :class:`hevr.Viewer` shows its frames in a
small anywidget (:func:`drag_image`): an ``<img>`` fed with the PNG bytes of the frame (the
``value`` trait, as ``Image`` has) whose front end — the ES module ``_ESM`` below, a string
that anywidget loads in the browser — turns pointer drags and wheel turns into custom messages
``{"type": "camera", "dx", "dy", "wheel", "release"}`` to the kernel:

* ``dx``, ``dy``: the pointer's movement since the last message, as fractions of the image's
  shown width and height (independent of how large the browser draws it);
* ``wheel``: the wheel's ``deltaY`` in pixels since the last message (lines and pages
  converted);
* ``release``: the button went up (or the pointer was lost) after these movements.

**Throttling.** The front end sends one message and then waits for the kernel's answer
``{"type": "done"}`` — sent after the frame of that message is on show (or refused) — adding up
every pointer event meanwhile. While a render is in flight no message queues up; the next one
carries the sum of what happened, so the camera goes to the *latest* pointer position (the
movements telescope: none is lost, none is rendered twice). A release waits its turn the same
way.

**One source of truth.** :class:`Orbit`, on the kernel side, turns a message into new values of
the viewer's camera *sliders* — azimuth −= 180° × ``dx`` (the volume turns with the pointer),
elevation += 180° × ``dy`` clamped to the slider's range, view angle × 2^(``wheel``/500) clamped
to its range (the wheel zooms), each slider set to the nearest of its steps (1°: a browser's
slider snaps any other value and sends it back, which would render again; the exact position
is kept, so slow drags add up) — and then takes the sliders' own path: the viewer's
:meth:`hevr.Viewer._moved` renders a coarse frame at the pyramid ``preview`` level during a drag
(the full frame on a store without a pyramid), and the release renders the full frame. A wheel
turn has no release: its preview is followed by the full frame after the viewer's ``settle``
seconds, as for a slider. The request sent to the cluster is the viewer's, unchanged: camera,
sampling, step, level and channel, never a colour.

Every message path is also a method (:meth:`Orbit.drag`, :meth:`Orbit.zoom`), so tests drive
the drag headlessly; ``tests/test_viewer_browser.py`` drags in a real browser.
"""

from __future__ import annotations

import functools
import io
import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from ..image.display import to_uint8

if TYPE_CHECKING:
    from .widget import Viewer

log = logging.getLogger(__name__)

DEGREES_PER_WIDTH = 180.0  # a drag across the whole image turns the camera by half a circle
WHEEL_PIXELS_PER_DOUBLING = 500.0  # wheel deltaY that doubles (or halves) the view angle

_ESM = r"""
function render({ model, el }) {
  const img = document.createElement("img");
  img.className = "hevr-drag";
  img.draggable = false;
  img.alt = img.title = "drag to orbit, wheel to zoom";
  img.style.cssText = "display:block; cursor:grab; touch-action:none; user-select:none; image-rendering:pixelated;";
  img.dataset.frames = "0";
  let url = null, frames = 0;
  const size = () => {
    img.style.width = model.get("width") + "px";
    img.style.height = model.get("height") + "px";
  };
  const show = () => {
    const v = model.get("value");
    if (!v || !v.byteLength) return;
    const next = URL.createObjectURL(new Blob([v], { type: "image/png" }));
    img.src = next;
    if (url) URL.revokeObjectURL(url);
    url = next;
    frames += 1;
    img.dataset.frames = String(frames);
  };
  // movements not yet sent; busy: a message is out and its "done" has not come back
  let last = null, dx = 0, dy = 0, wheel = 0, release = false, busy = false, since = 0, sent = 0;
  const flush = () => {
    if (busy && performance.now() - since < 60000) return;  // a lost answer frees it after a minute
    busy = false;
    if (!(dx || dy || wheel || release)) return;
    const w = img.clientWidth || 1, h = img.clientHeight || 1;
    model.send({ type: "camera", dx: dx / w, dy: dy / h, wheel: wheel, release: release });
    dx = dy = wheel = 0;
    release = false;
    busy = true;
    since = performance.now();
    sent += 1;
    img.dataset.sent = String(sent);
  };
  img.addEventListener("pointerdown", (e) => {
    if (e.button !== 0) return;
    e.preventDefault();
    img.setPointerCapture(e.pointerId);
    last = [e.clientX, e.clientY];
    img.style.cursor = "grabbing";
  });
  img.addEventListener("pointermove", (e) => {
    if (!last) return;
    dx += e.clientX - last[0];
    dy += e.clientY - last[1];
    last = [e.clientX, e.clientY];
    flush();
  });
  const up = (e) => {
    if (!last) return;
    dx += e.clientX - last[0];
    dy += e.clientY - last[1];
    last = null;
    release = true;
    img.style.cursor = "grab";
    flush();
  };
  img.addEventListener("pointerup", up);
  img.addEventListener("pointercancel", up);
  img.addEventListener("wheel", (e) => {
    e.preventDefault();  // zoom the frame, do not scroll the notebook
    wheel += e.deltaY * (e.deltaMode === 1 ? 16 : e.deltaMode === 2 ? (img.clientHeight || 256) : 1);
    flush();
  }, { passive: false });
  model.on("msg:custom", (msg) => {
    if (msg && msg.type === "done") {
      busy = false;
      flush();
    }
  });
  model.on("change:value", show);
  model.on("change:width", size);
  model.on("change:height", size);
  size();
  show();
  el.appendChild(img);
  return () => { if (url) URL.revokeObjectURL(url); };
}
export default { render };
"""


@functools.lru_cache(maxsize=1)
def _image_class() -> type:
    """The anywidget class (defined on first use: anywidget is an optional dependency)."""
    import anywidget
    import traitlets

    class DragImage(anywidget.AnyWidget):
        """A PNG frame shown in an ``<img>`` that reports drags and wheel turns (module docstring)."""

        _esm = _ESM
        value = traitlets.Bytes(b"").tag(sync=True)
        width = traitlets.Int(256).tag(sync=True)
        height = traitlets.Int(256).tag(sync=True)

    return DragImage


def drag_image(width: int, height: int) -> Any:
    """A new drag surface showing frames at ``width`` × ``height`` CSS pixels."""
    return _image_class()(width=int(width), height=int(height))


def png(arr: np.ndarray, window: tuple[float, float] | None, size: tuple[int, int]) -> bytes:
    """The frame as PNG bytes of ``size`` (W, H): a preview's fewer pixels are shown enlarged."""
    buf = io.BytesIO()
    im = Image.fromarray(to_uint8(arr, window))
    shown = (int(size[0]), int(size[1]))
    (im if im.size == shown else im.resize(shown, Image.Resampling.NEAREST)).save(buf, format="PNG")
    return buf.getvalue()


def _number(content: dict, key: str) -> float:
    value = content.get(key, 0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{key}: expected a finite number, got {value!r}")
    return float(value)


class Orbit:
    """Drags and wheel turns on the viewer's image → the viewer's camera sliders → frames.

    Parameters
    ----------
    viewer : hevr.Viewer
        Its ``image`` is the drag surface (:func:`drag_image`); its sliders are set and its
        slider path renders.

    Attributes
    ----------
    messages : int
        Messages received from the front end (each answered with ``{"type": "done"}``).
    """

    def __init__(self, viewer: Viewer) -> None:
        self.viewer = viewer
        self.messages = 0
        self._exact: tuple[float, float, float] | None = None  # the drag's camera before snapping to steps
        viewer.image.on_msg(self._message)

    def _message(self, _widget: Any, content: Any, _buffers: Any) -> None:
        """A front-end message: apply it, then answer "done" so the front end sends the next."""
        self.messages += 1
        try:
            if not isinstance(content, dict) or content.get("type") != "camera":
                log.warning("viewer: ignored a message from the front end: %r", content)
                return
            try:
                dx, dy, wheel = (_number(content, k) for k in ("dx", "dy", "wheel"))
            except ValueError as exc:
                log.warning("viewer: ignored a camera message: %s", exc)
                return
            self.move(dx, dy, wheel, release=bool(content.get("release", False)))
        finally:
            self.viewer.image.send({"type": "done"})

    def _sliders(self) -> tuple[Any, Any, Any]:
        v = self.viewer
        return v.azimuth, v.elevation, v.view_angle

    def _set(self, exact: tuple[float, float, float]) -> bool:
        """Set the camera sliders to ``exact`` snapped to their steps, without rendering; True
        when one of them changed. A slider in the browser snaps a value between steps and sends
        it back (another render); a value on a step stays. ``exact`` is kept, so movements
        smaller than a step add up."""
        v = self.viewer
        before = tuple(s.value for s in self._sliders())
        held, v._held = v._held, True
        try:
            for s, x in zip(self._sliders(), self._snap(exact)):
                s.value = x
        finally:
            v._held = held
        self._exact = exact
        return tuple(s.value for s in self._sliders()) != before

    def _start(self) -> tuple[float, float, float]:
        """The exact camera the last drag left, or the sliders' when they moved since (or never dragged)."""
        azimuth, elevation, view_angle = self._sliders()
        now = (float(azimuth.value), float(elevation.value), float(view_angle.value))
        if self._exact is not None and all(abs(a - b) < 1e-6 for a, b in zip(self._snap(self._exact), now)):
            return self._exact
        return now

    def _snap(self, exact: tuple[float, float, float]) -> tuple[float, ...]:
        """The slider values of an exact camera: on the sliders' steps, in their ranges."""
        return tuple(
            min(max(s.min + round((x - s.min) / s.step) * s.step, s.min), s.max) for s, x in zip(self._sliders(), exact)
        )

    def move(self, dx: float = 0.0, dy: float = 0.0, wheel: float = 0.0, release: bool = False) -> dict | None:
        """Apply one message: orbit by a pointer movement of (``dx``, ``dy``) image widths and
        heights, zoom by a wheel turn of ``wheel`` pixels, then render once.

        Azimuth −= 180° × ``dx`` (wrapping around the slider's range), elevation += 180° × ``dy``
        and view angle × 2^(``wheel``/500) (positive: a wider view, away from the volume), both
        clamped to their sliders' ranges. During a drag the preview is rendered (the full frame
        without a pyramid) and the settle timer is not started; after a wheel turn alone it is,
        as for a slider; ``release=True`` ends the drag with the full frame.

        Returns
        -------
        dict or None
            The history entry of the frame rendered, or None when nothing was rendered (no
            movement, a release with nothing pending, or the viewer held).
        """
        v = self.viewer
        az, el, va = self._start()
        az = (az - DEGREES_PER_WIDTH * dx - v.azimuth.min) % (v.azimuth.max - v.azimuth.min) + v.azimuth.min
        el = min(max(el + DEGREES_PER_WIDTH * dy, v.elevation.min), v.elevation.max)
        va *= 2.0 ** min(max(wheel / WHEEL_PIXELS_PER_DOUBLING, -64.0), 64.0)
        va = min(max(va, v.view_angle.min), v.view_angle.max)
        changed = self._set((az, el, va))
        if v._held:
            return None
        n = len(v.history)
        if release:
            if changed:
                v._pending = True  # the full frame of the final position, no preview first
            v.settle()
        elif changed:
            v._moved(wait=not (dx or dy))
        return v.history[-1] if len(v.history) > n else None

    def drag(self, dx: float, dy: float, release: bool = False) -> dict | None:
        """Orbit by a pointer movement of (``dx``, ``dy``) image widths and heights (:meth:`move`)."""
        return self.move(dx, dy, release=release)

    def zoom(self, wheel: float) -> dict | None:
        """Zoom by a wheel turn of ``wheel`` pixels (:meth:`move`)."""
        return self.move(wheel=wheel)
