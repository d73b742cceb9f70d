"""Anatomical camera presets: ``Camera.orbit(..., view="anterior")`` and friends.

hevr's loaders return scans in the RAS+ patient frame (:mod:`hevr.volume.orientation`):
world +x is the patient's Right, +y Anterior, +z Superior. A view names the side of the
patient the camera stands on, and the image's up direction:

==========  ===============  ========  ==================================================
view        camera at        image up  the image's left shows
==========  ===============  ========  ==================================================
anterior    +y (front)       superior  the patient's right (radiology: facing the patient)
posterior   -y (back)        superior  the patient's left
left        -x (left side)   superior  anterior (the patient faces the image's left)
right       +x (right side)  superior  posterior (the patient faces the image's right)
superior    +z (above)       anterior  the patient's left (looking down on the head)
inferior    -z (below)       anterior  the patient's right (radiology's axial convention:
                                       seen from the feet, anterior up)
==========  ===============  ========  ==================================================

Superior and inferior both put anterior at the top, so one is the other's left-right mirror
(as posterior is anterior's).

Azimuth and elevation
---------------------
Each view is a *back* vector ``B`` (centre -> camera) and an *up* vector ``U``; with
``S = U x B`` (the side a positive azimuth turns towards) the camera sits at

    ``centre + distance * (cos(el) (cos(az) B + sin(az) S) + sin(el) U)``

with view-up ``-sin(el) (cos(az) B + sin(az) S) + cos(el) U``: azimuth rotates the camera
right-handedly about the view's up axis (the patient's superior axis for the four side
views, the anterior axis for superior/inferior), and elevation tilts it towards that up
axis. This is exactly :meth:`Camera.orbit`'s own convention with ``B = +z``, ``U = +y``
(``view=None``), so a positive azimuth always moves the camera towards the image's right.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.validate import check_choice

__all__ = ["VIEWS", "view_axes", "view_offset"]

#: The anatomical views of :meth:`hevr.Camera.orbit`, in the order of the module docstring.
VIEWS = ("anterior", "posterior", "left", "right", "superior", "inferior")

# view -> (back B: centre -> camera, up U), RAS+ world axes.
_AXES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "anterior": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "posterior": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "left": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "right": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "superior": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "inferior": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
}


def view_axes(view: str) -> tuple[np.ndarray, np.ndarray]:
    """``(back, up)`` of ``view``: unit RAS+ vectors (camera side, image up).

    Examples
    --------
    >>> [v.tolist() for v in view_axes("anterior")]
    [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    >>> view_axes("front")
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: view: expected one of anterior, posterior, left, right, superior, inferior, got 'front'
    """
    check_choice("view", view, VIEWS)
    back, up = _AXES[view]
    return np.array(back), np.array(up)


def view_offset(view: str, azimuth_rad: float, elevation_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit ``(offset, view_up)`` of ``view`` turned by azimuth and elevation (radians).

    ``offset`` points from the volume's centre to the camera (module docstring).

    Examples
    --------
    >>> off, up = view_offset("anterior", math.pi / 2, 0.0)   # a quarter turn: to the patient's left
    >>> np.round(off, 12).tolist(), up.tolist()
    ([-1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    """
    back, up = view_axes(view)
    side = np.cross(up, back)
    ca, sa = math.cos(azimuth_rad), math.sin(azimuth_rad)
    ce, se = math.cos(elevation_rad), math.sin(elevation_rad)
    horizontal = ca * back + sa * side
    return ce * horizontal + se * up, -se * horizontal + ce * up
