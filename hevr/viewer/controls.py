"""The viewer's controls: the ipywidgets :class:`hevr.viewer.widget.Viewer` is made of.

The camera sliders, the mode, sampling and gradient toggles, the density slider, one row of the
transfer-function editor and the layout of the whole viewer are built here, so that the viewer
holds only what they do (it observes them and renders). The ipywidgets module is passed in as
``W`` by the viewer, which imports it (and says when it is missing) as it is made.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ..rendering.geometry.camera import Camera
from ..rendering.planning.modes import parse_color

__all__ = ["arrange", "camera_sliders", "density_slider", "hex_colour", "mode_toggles", "node_row", "slider_camera"]


def hex_colour(colour: Any) -> str:
    """'#rrggbb' of any colour hevr accepts.

    >>> hex_colour("red"), hex_colour((0, 0.5, 1))
    ('#ff0000', '#0080ff')
    """
    r, g, b = parse_color(colour)
    return "#{:02x}{:02x}{:02x}".format(*(int(round(255 * v)) for v in (r, g, b)))


def camera_sliders(W: Any, packed: bool, continuous: bool) -> tuple[Any, Any, Any]:
    """The azimuth, elevation and view-angle sliders at their starting positions.

    Parameters
    ----------
    W : module
        ipywidgets.
    packed : bool
        A packed store's views: azimuth 0, elevation 10, leaning less than 45° towards its axis.
    continuous : bool
        Report every move (the viewer has a preview level: cheap coarse frames), else on release.

    Returns
    -------
    tuple of ipywidgets.FloatSlider
        (azimuth, elevation, view angle), in degrees.
    """
    slider: dict[str, Any] = dict(continuous_update=continuous, readout_format=".0f")
    azimuth = W.FloatSlider(
        value=0.0 if packed else 30.0, min=-180.0, max=180.0, step=1.0, description="azimuth", **slider
    )
    tilt = 44.0 if packed else 89.0  # a packed store's views lean less than 45° towards its axis
    elevation = W.FloatSlider(
        value=10.0 if packed else 20.0, min=-tilt, max=tilt, step=1.0, description="elevation", **slider
    )
    view_angle = W.FloatSlider(value=30.0, min=5.0, max=90.0, step=1.0, description="view angle", **slider)
    return azimuth, elevation, view_angle


def slider_camera(
    ev: Any, angles: tuple[float, float, float], width: int, height: int, view: str | None = None
) -> Camera:
    """The camera the sliders describe (:meth:`hevr.Camera.orbit`).

    Parameters
    ----------
    ev : EncryptedVolume
        The store looked at.
    angles : tuple of float
        (azimuth, elevation, view angle) in degrees.
    width, height : int
        Frame size in pixels.
    view : str, optional
        A packed store's anatomical view (:mod:`hevr.rendering.geometry.views`): the camera is
        then parallel, and the view angle zooms it (the frame's half-height shrinks with it).
    """
    azimuth, elevation, view_angle = angles
    if view is not None:
        cam = Camera.orbit(
            ev, azimuth=azimuth, elevation=elevation, width=width, height=height, parallel=True, view=view
        )
        assert cam.parallel_scale is not None  # a parallel camera's half-height
        return dataclasses.replace(cam, parallel_scale=cam.parallel_scale * view_angle / 30.0)
    return Camera.orbit(ev, azimuth=azimuth, elevation=elevation, width=width, height=height, view_angle=view_angle)


def mode_toggles(W: Any, modes: list[str], mode: str, sampling: str, gradient: bool) -> tuple[Any, Any, Any]:
    """The mode and sampling toggle buttons and the gradient box (shown when ``gradient``: the store
    has the gradient channel)."""
    mode_buttons = W.ToggleButtons(options=modes, value=mode, description="mode")
    sampling_buttons = W.ToggleButtons(options=["nearest", "trilinear"], value=sampling, description="sampling")
    box = W.Checkbox(
        value=False, description="gradient", indent=False, layout=W.Layout(display=None if gradient else "none")
    )
    return mode_buttons, sampling_buttons, box


def density_slider(W: Any, value: float, description: str) -> Any:
    """A normalised density in [0, 1], three decimals, reported on release (the emphasised density,
    a transfer-function node's)."""
    return W.FloatSlider(
        value=float(value),
        min=0.0,
        max=1.0,
        step=0.001,
        readout_format=".3f",
        description=description,
        continuous_update=False,
    )


def node_row(W: Any, density: float, colour: Any) -> tuple[Any, Any, Any]:
    """One row of the transfer-function editor: (density slider, colour picker, remove button)."""
    d = density_slider(W, density, "node")
    c = W.ColorPicker(value=hex_colour(colour), concise=True)
    rm = W.Button(icon="trash", tooltip="remove this node", layout=W.Layout(width="36px"))
    return d, c, rm


def arrange(W: Any, image: Any, controls: list[Any], status: Any) -> Any:
    """The whole viewer: the frame beside its controls (one column), the status line below."""
    return W.VBox([W.HBox([image, W.VBox(controls)]), status])
