"""``hevr.Viewer``: an interactive viewer of an encrypted volume in the key holder's notebook.

The notebook that holds the private key drives renders on the (untrusted) cluster and
decrypts the frames it gets back; the cluster sees only ciphertexts and the public render
request — camera, sampling, step, pyramid level and stored channel, never the density, the
transfer function or its colours (client finishing, :mod:`hevr.colour`). The viewer is a thin
layer of widgets over :func:`hevr.render_frame` and :meth:`hevr.Frame.recolour`:

* **camera**: azimuth, elevation and view-angle sliders (:meth:`hevr.Camera.orbit`); a frame
  is rendered when a slider is released (``continuous_update=False``), one render per move;
* **dragging on the image** orbits the camera and the wheel zooms (the view angle): the frame is
  an anywidget (:mod:`hevr.viewer.drag`) whose pointer events set the camera sliders — one source of
  truth, the sliders follow the drag — and take the sliders' path below: coarse frames while
  dragging, the full frame on release; one message in flight at a time, the pointer's
  movements meanwhile added up (the latest position is rendered, no render queue);
* **mode and sampling**: X-ray, density emphasis (a density slider), transfer function; a
  *gradient* box (stores encrypted with ``gradient=True``) weights emphasis and transfer-function
  samples by the gradient magnitude;
* **transfer-function editor**: one row per node — density slider, colour picker, remove
  button — and an *add node* button; nodes with the same density are refused by
  :func:`hevr.render` and the message shows in the status line (the frame stays);
* **re-colouring on the client**: the last frame is kept decrypted as per-pixel component
  means (a :class:`hevr.Frame`); emphasis and TF images are linear in them, so a new density,
  colour, node or mode on an unchanged camera, level, sampling and channel is a numpy product
  of milliseconds in the notebook — no request reaches the cluster (``client_recolour`` and
  ``map_tasks == 0`` in :attr:`Viewer.history`). A new camera, level, sampling or channel
  (X-ray ↔ emphasis/TF, the gradient box) renders again;
* **status line**: the frame time end to end (request → decrypted frame), map tasks, whether
  the cluster reused cached ray sums, or "re-coloured on the client in N ms, no server"; and the
  largest pixel error against the plaintext reference when the notebook has the plaintext
  volume (``volume=``), next to :func:`hevr.error_bound`.

* **progressive viewing**: on a store with a pyramid (:func:`hevr.build_pyramid`) the camera
  sliders report every move and each move renders a coarse frame at pyramid level ``preview``
  (default: the coarsest of levels 1–2 the store has) with 2^level times fewer pixels per axis,
  shown enlarged — about 8^level times fewer ray-voxel pairs; once the
  sliders have been still for ``settle`` seconds (or on :meth:`Viewer.settle`) the full frame
  follows. Without a pyramid, sliders render on release.

* **packed stores** (``encrypt_volume(..., layout="packed")``, :mod:`hevr.rendering.packed`): the
  camera is parallel and orbits the packing axis, starting from an anatomical view the store can
  serve (``"anterior"`` for a store packed along z, the patient's superior axis: azimuth turns about
  it, elevation leans towards it, at most 44°); frames come whole from :func:`hevr.render_frame`
  (X-ray previews from a level the owner encrypted; the settled frame verified on a verifiable store;
  a store with the vector channel offers emphasis and transfer functions, re-coloured in numpy).

Every widget change calls :meth:`Viewer.refresh` synchronously, so the viewer can be driven
headlessly — set a widget's ``value`` in code, as a test does, and the render runs.
"""

from __future__ import annotations

import html
import logging
import threading
import time
from typing import Any

import numpy as np

from ..colour import Frame
from ..crypto.keys import PrivateKey
from ..errors import HevrError, ParameterError
from ..paper import PAPER_DENSITIES, PAPER_TF1
from ..rendering.geometry.camera import Camera
from ..rendering.pipeline.stream import render_frame
from ..store.reader import EncryptedVolume
from ..volume.pyramid import check_level
from .checks import check_settle, check_viewer, import_widgets, viewer_modes
from .controls import arrange, camera_sliders, density_slider, mode_toggles, node_row, slider_camera
from .drag import Orbit, drag_image, png
from .report import compare, status_text

log = logging.getLogger(__name__)

__all__ = ["Viewer"]


class Viewer:
    """Interactive viewer of an encrypted volume (ipywidgets; the key holder's notebook).

    Parameters
    ----------
    ev : EncryptedVolume
        The store to render (opened, or persisted with :meth:`EncryptedVolume.persist`).
    private_key : PrivateKey
        Decrypts the frames here, in the notebook; it is never sent anywhere.
    volume : numpy.ndarray, optional
        The plaintext volume, when the notebook has it: each frame is compared with
        :func:`hevr.render_plain` and the largest error is shown.
    width, height : int
        Frame size in pixels.
    mode : {"xray", "emphasize", "tf"}, optional
        Default: the first the store offers (X-ray if it has the scalar channel).
    sampling : {"nearest", "trilinear"}
    nodes : list of (density, colour), optional
        Initial transfer function (default: the paper's first one).
    density : float, optional
        Initial emphasised density (default 0.653, the paper's small sphere).
    client : distributed.Client, optional
        Passed to :func:`hevr.render_frame`: a LocalCluster's, or another scheduler's declared
        with :func:`hevr.own_cluster` (else :class:`hevr.ForeignClusterError`).
    step : float
        Sample spacing along the rays.
    preview : int, optional
        Pyramid level of the frames shown while a camera slider moves (0: none). Default: the
        coarsest of levels 1–2 the store has, else 0.
    settle : float or None
        Seconds without slider movement before the full frame replaces a preview; None: only
        :meth:`settle` does it (headless use).
    show : bool
        Render the first frame now.

    Attributes
    ----------
    history : list of dict
        One entry per refresh: the request, ``map_tasks`` (None for a remote frame: the server
        does not say), ``reused_ray_sums``,
        ``client_recolour`` (True: re-coloured in the notebook, no request to the cluster),
        ``seconds`` (end to end: request to the image on show), ``error`` (or None) and
        ``bound``; or ``error_message`` when the render (or colouring) was refused.
    frame : hevr.Frame or None
        The last decrypted frame of component means, re-coloured while only the colouring changes.
    image : anywidget.AnyWidget
        The frame on show (PNG bytes in ``value``); dragging on it orbits, the wheel zooms.
    orbit : hevr.viewer.drag.Orbit
        Turns drags and wheel turns on :attr:`image` into slider values (``orbit.drag(dx, dy)``,
        ``orbit.zoom(wheel)`` drive it from code).
    widget : ipywidgets.VBox
        The whole viewer (displayed by the notebook when the viewer is the cell's value).
    """

    def __init__(
        self,
        ev: EncryptedVolume,
        private_key: PrivateKey,
        *,
        volume: np.ndarray | None = None,
        width: int = 128,
        height: int = 128,
        mode: str | None = None,
        sampling: str = "nearest",
        nodes: Any = None,
        density: float | None = None,
        client: Any = None,
        step: float = 1.0,
        preview: int | None = None,
        settle: float | None = 0.6,
        show: bool = True,
    ) -> None:
        W = import_widgets()
        check_viewer(ev, private_key, volume, client)
        self.ev, self._key, self.volume, self.client, self.step = ev, private_key, volume, client, float(step)
        self.size = (width, height)
        Camera.orbit(ev, width=width, height=height)  # validates the size once, here
        packing = ev.meta.packing
        self.packed = packing is not None
        # a packed store: parallel views orbiting its packing axis (superior z: "anterior", whose up is z)
        self.view = {0: "anterior", 1: "superior"}.get(packing.axis) if packing is not None else None
        self.history: list[dict[str, Any]] = []
        self.frame: Frame | None = None
        self._frame_view: tuple[Any, ...] | None = None  # what the frame depends on: camera, level, sampling, channel
        self._held = False
        modes, mode = viewer_modes(ev, mode)
        self.preview = min(ev.levels, 2) if preview is None else check_level(preview, ev.levels, "preview")
        self.settle_after = check_settle(settle)
        self._timer: threading.Timer | None = None
        self._pending = False
        self._lock = threading.RLock()
        # with a preview level, camera sliders report every move (cheap coarse frames); else on release
        self.azimuth, self.elevation, self.view_angle = camera_sliders(W, self.packed, bool(self.preview))
        self.mode, self.sampling, self.gradient = mode_toggles(W, modes, mode, sampling, ev.meta.gradient is not None)
        self.density = density_slider(W, PAPER_DENSITIES[1] if density is None else float(density), "density")
        self._W = W
        self._rows = W.VBox()
        self.add_button = W.Button(description="add node", icon="plus")
        self.add_button.on_click(lambda _b: self.add_node())
        self.image = drag_image(max(256, width), max(256, height))  # drag to orbit, wheel to zoom
        self.orbit = Orbit(self)
        self.status = W.HTML(value="")
        self.node_rows: list[tuple[Any, Any, Any]] = []
        with self.hold():
            for d, c in PAPER_TF1 if nodes is None else nodes:
                self.add_node(d, c)
        for w in (self.azimuth, self.elevation, self.view_angle):
            w.observe(self._moved, names="value")
        for w in (self.mode, self.sampling):
            w.observe(self._changed, names="value")
        self.gradient.observe(lambda ch: self._changed(ch, only="vector"), names="value")
        self.density.observe(lambda ch: self._changed(ch, only="emphasize"), names="value")
        self.tf_box = W.VBox([self._rows, self.add_button])
        controls = [self.azimuth, self.elevation, self.view_angle, self.mode, self.sampling, self.gradient]
        self.widget = arrange(W, self.image, [*controls, self.density, self.tf_box], self.status)
        self._layout()
        if show:
            self.refresh()

    # -- the request ------------------------------------------------------------------------
    def camera(self, level: int = 0) -> Camera:
        """The camera of the current slider positions; for a preview at pyramid ``level``, with
        2^level times fewer pixels per axis (a level's voxels are 2^level times larger)."""
        w, h = (max(1, d >> level) for d in self.size)
        angles = (self.azimuth.value, self.elevation.value, self.view_angle.value)
        return slider_camera(self.ev, angles, w, h, self.view if self.packed else None)

    def nodes(self) -> list[tuple[float, str]]:
        """The transfer function of the editor: (density, '#rrggbb') per row, in row order."""
        return [(float(d.value), str(c.value)) for d, c, _ in self.node_rows]

    def request(self) -> dict[str, Any]:
        """Keyword arguments of :func:`hevr.render_frame` (and :func:`hevr.render_plain`) for the current state."""
        kw: dict[str, Any] = {"mode": self.mode.value, "sampling": self.sampling.value, "step": self.step}
        if self.packed:  # one sample per slice: no step
            del kw["step"]
        if self.mode.value == "emphasize":
            kw["density"] = float(self.density.value)
        elif self.mode.value == "tf":
            kw["nodes"] = self.nodes()
        if self.mode.value != "xray" and self.gradient.value:
            kw["gradient"] = True
        return kw

    # -- the transfer-function editor ----------------------------------------------------------
    def add_node(self, density: float = 0.5, colour: Any = "white") -> None:
        """Append a node row (density slider, colour picker, remove button); renders once."""
        W = self._W
        row = d, c, rm = node_row(W, density, colour)
        rm.on_click(lambda _b, row=row: self.remove_node(self.node_rows.index(row)))
        d.observe(lambda ch: self._changed(ch, only="tf"), names="value")
        c.observe(lambda ch: self._changed(ch, only="tf"), names="value")
        self.node_rows.append(row)
        self._rows.children = [W.HBox(list(r)) for r in self.node_rows]
        self._changed(only="tf")

    def remove_node(self, index: int) -> None:
        """Remove node ``index`` (the last node stays: a transfer function needs one)."""
        if not isinstance(index, int) or not -len(self.node_rows) <= index < len(self.node_rows):
            raise ParameterError(f"index: expected a node index in [0, {len(self.node_rows)}), got {index!r}")
        if len(self.node_rows) <= 1:
            self._say("a transfer function needs at least one node")
            return
        self.node_rows.pop(index)
        self._rows.children = [self._W.HBox(list(r)) for r in self.node_rows]
        self._changed(only="tf")

    # -- rendering --------------------------------------------------------------------------
    def hold(self) -> _Hold:
        """Context manager: change several widgets, then render once (``with viewer.hold(): ...``)."""
        return _Hold(self)

    def _changed(self, _change: Any = None, only: str | None = None) -> None:
        """A widget changed; ``only``: it matters in that mode alone (a hidden widget renders nothing)."""
        self._layout()
        current = "vector" if only == "vector" and self.mode.value != "xray" else self.mode.value
        if not self._held and (only is None or current == only):
            self.refresh()

    def _moved(self, change: Any = None, wait: bool = True) -> None:
        """A camera slider moved: a coarse frame now (when the store has a pyramid level), the
        full frame once the sliders have been still for ``settle`` seconds (or on :meth:`settle`;
        ``wait=False``: only then — a drag on the image ends with it)."""
        if self._held or (change is not None and abs(change["new"] - change["old"]) < 1e-6):
            return  # < 1e-6°: a browser's slider sending back the value it was given, recomputed
        if not self.preview:
            self.refresh()
            return
        self.refresh(level=self.preview)
        self._pending = True
        if self._timer is not None:
            self._timer.cancel()
        if self.settle_after is not None and wait:
            self._timer = threading.Timer(self.settle_after, self.settle)
            self._timer.daemon = True
            self._timer.start()

    def settle(self) -> dict[str, Any] | None:
        """Render the full frame if the last one shown was a preview; returns its history entry."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if not self._pending:
            return None
        return self.refresh()

    def _layout(self) -> None:
        if hasattr(self, "tf_box"):
            self.density.layout.display = None if self.mode.value == "emphasize" else "none"
            self.tf_box.layout.display = None if self.mode.value == "tf" else "none"

    def _say(self, text: str) -> None:
        self.status.value = f"<span style='color:#b00'>{html.escape(text)}</span>"

    def refresh(self, level: int = 0) -> dict[str, Any]:
        """Render, decrypt and show the current state (at pyramid ``level``: a preview); returns
        (and appends to :attr:`history`) what happened."""
        with self._lock:
            if not level:
                self._pending = False
            return self._refresh(level)

    def _view(self, cam: Camera, level: int, kw: dict[str, Any]) -> tuple[Any, ...]:
        """What a frame of component sums depends on (anything else is colouring): the camera,
        the level, the sampling, the step and the stored channel the mode reads."""
        channel = "scalar" if kw["mode"] == "xray" else "gradient" if kw.get("gradient") else "vector"
        return cam.key(), level, kw["sampling"], kw.get("step", 1.0), channel

    def _refresh(self, level: int) -> dict[str, Any]:
        kw = self.request()
        cam = self.camera(level)
        entry: dict[str, Any] = {"request": kw, "camera": cam.to_dict(), "level": level}
        view = self._view(cam, level, kw)
        t0 = time.perf_counter()
        kept = self.frame if view == self._frame_view else None
        recolour = kept is not None
        try:
            if kept is not None:  # only the colouring changed: numpy here, nothing sent anywhere
                frame = kept
                arr = frame.recolour(kw["mode"], kw.get("density"), kw.get("nodes"))
            else:
                # a preview is not verified (it must come fast); the settled full frame is
                frame = render_frame(
                    self.ev,
                    cam,
                    self._key,
                    client=self.client,
                    progress=False,
                    level=level or None,
                    verify=False if level else None,
                    **kw,
                )
                arr = frame.image
        except HevrError as exc:  # e.g. two nodes at one density: say it, keep the last frame
            entry["error_message"] = str(exc)
            self.history.append(entry)
            self._say(str(exc))
            return entry
        seconds = time.perf_counter() - t0
        if not recolour:
            self.frame, self._frame_view = frame, view
        err: float | None = None
        bound: float | None = None
        window: tuple[float, float] | None = None
        if self.volume is not None:
            err, bound, window = compare(self.ev, self.volume, cam, level, kw, arr)
        stats = frame.stats
        # a remote frame's server does not say (issue 48: what it reused would tell of other tokens' views)
        tasks, reused = stats.get("map_tasks"), bool(stats.get("reused_ray_sums"))
        entry.update(
            map_tasks=0 if recolour else tasks,
            reused_ray_sums=True if recolour else reused,
            client_recolour=recolour,
            seconds=seconds,
            error=err,
            bound=bound,
        )
        self.history.append(entry)  # before the image: an observer of image.value sees this entry last
        self.image.value = png(arr, window, self.size)
        verified = bool(stats.get("verified"))
        text = status_text(
            kw, level, seconds, recolour=recolour, reused=reused, tasks=tasks, verified=verified, err=err, bound=bound
        )
        entry["verified"] = verified if not recolour else entry.get("verified")
        self.status.value = html.escape(text)
        log.info("viewer: %s", text)
        return entry

    def __repr__(self) -> str:
        kw = self.request()
        extra = {"emphasize": f", density {kw.get('density')}", "tf": f", {len(self.node_rows)} TF nodes"}
        return (
            f"hevr.Viewer({kw['mode']}/{kw['sampling']}{extra.get(kw['mode'], '')}, {self.size[0]}x{self.size[1]}"
            f", azimuth {self.azimuth.value:g}, elevation {self.elevation.value:g}; {len(self.history)} frames)"
        )

    def _repr_mimebundle_(self, **kwargs: Any) -> dict[str, Any]:
        """The widget for Jupyter front ends; this short text where widgets cannot show."""
        data: dict[str, Any] = self.widget._repr_mimebundle_(**kwargs)
        data["text/plain"] = repr(self)
        return data


class _Hold:
    """Defers the viewer's renders until the block ends, then renders once."""

    def __init__(self, viewer: Viewer) -> None:
        self.viewer = viewer

    def __enter__(self) -> Viewer:
        self.outer = self.viewer._held
        self.viewer._held = True
        return self.viewer

    def __exit__(self, *exc: Any) -> None:
        self.viewer._held = self.outer
        if not self.outer and exc[0] is None and hasattr(self.viewer, "widget"):
            self.viewer.refresh()
