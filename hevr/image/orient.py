"""Slices shown the way radiology viewers show them: :func:`orient_slice`.

A slice comes back from :func:`hevr.render_slice` in the plane's own pixel order: row ``r``,
column ``c`` at ``origin + c·du·u + r·dv·v`` (:mod:`hevr.rendering.geometry.plane`), so the helpers
:meth:`hevr.Plane.axial` / ``coronal`` / ``sagittal`` give the raw array order
(``vol[k]``, ``vol[:, j, :]``, ``vol[:, :, i]``): a coronal slice with the head at the bottom,
an axial one with the front at the bottom. The PNGs of ``hevr decrypt`` and
``hevr.save_png(..., plane=...)`` are turned (flips, or a transpose for a plane whose
columns run vertically) into the **radiological convention** of the world frame RAS+
(+x the patient's right, +y anterior, +z superior; :mod:`hevr.volume.orientation`):

=========  ====================  ===================  ======================================
plane      normal closest to     image top            image left
=========  ====================  ===================  ======================================
axial      z                     anterior             the patient's right (seen from the feet)
coronal    y                     superior             the patient's right (facing the patient)
sagittal   x                     superior             anterior (seen from the patient's left)
=========  ====================  ===================  ======================================

``convention="neurological"`` puts the patient's left on the image's left in axial and
coronal slices (sagittal is the same in both). An oblique plane is shown as the axis-aligned
plane its normal is closest to. A volume without a recorded patient frame (a phantom, a raw
array) is shown as if its axes were RAS+, like ``hevr render --view``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.validate import check_choice
from ..errors import ParameterError

__all__ = ["CONVENTIONS", "DEFAULT_CONVENTION", "describe_layout", "orient_slice", "slice_layout"]

CONVENTIONS = ("radiological", "neurological")
DEFAULT_CONVENTION = "radiological"

_X, _Y, _Z = np.eye(3)
# plane kind (the world axis its normal is closest to) -> (image right, image down), radiological.
_SCREEN = {"sagittal": (-_Y, -_Z), "coronal": (-_X, -_Z), "axial": (-_X, -_Y)}
_WORDS = {
    (0, 1): "the patient's right",
    (0, -1): "the patient's left",
    (1, 1): "anterior",
    (1, -1): "posterior",
    (2, 1): "superior",
    (2, -1): "inferior",
}


def _axes(plane: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` of a :class:`hevr.Plane` or of its ``to_dict()`` (a frame's ``info["camera"]``)."""
    try:
        u, v = (plane["u"], plane["v"]) if isinstance(plane, dict) else (plane.u, plane.v)
        u, v = np.asarray(u, dtype=np.float64).reshape(3), np.asarray(v, dtype=np.float64).reshape(3)
        ok = bool(np.isfinite(u).all() and np.isfinite(v).all() and np.linalg.norm(np.cross(u, v)) > 0)
    except (AttributeError, KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise ParameterError(f"plane: expected a hevr.Plane (or its to_dict()), got {type(plane).__name__}")
    return u, v


def slice_layout(plane: Any, convention: str = DEFAULT_CONVENTION) -> dict[str, Any]:
    """How :func:`orient_slice` turns a slice of ``plane`` for display.

    Returns
    -------
    dict
        ``kind`` ("axial", "coronal", "sagittal"), ``transpose``, ``flip_rows``, ``flip_cols``
        (applied in that order), and ``top``, ``left``: the anatomical directions at the
        displayed image's top and left (e.g. "superior", "the patient's right").

    Examples
    --------
    >>> from hevr.rendering.geometry.plane import Plane
    >>> lay = slice_layout(Plane.coronal((4, 3, 2), 1))
    >>> lay["kind"], lay["top"], lay["left"], lay["flip_rows"], lay["flip_cols"]
    ('coronal', 'superior', "the patient's right", True, True)
    """
    check_choice("convention", convention, CONVENTIONS)
    u, v = _axes(plane)
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    n = np.cross(u, v)
    kind = ("sagittal", "coronal", "axial")[int(np.argmax(np.abs(n)))]
    right, down = _SCREEN[kind]
    if convention == "neurological" and kind != "sagittal":
        right = -right
    transpose = abs(float(u @ down)) > abs(float(u @ right))  # the columns run vertically: swap
    cols, rows = (v, u) if transpose else (u, v)
    flip_cols, flip_rows = float(cols @ right) < 0, float(rows @ down) < 0

    def word(d: np.ndarray) -> str:
        a = int(np.argmax(np.abs(d)))
        return _WORDS[(a, 1 if d[a] > 0 else -1)]

    return {
        "kind": kind,
        "transpose": transpose,
        "flip_rows": flip_rows,
        "flip_cols": flip_cols,
        "top": word(-down),
        "left": word(-right),
        "convention": convention,
    }


def orient_slice(arr: np.ndarray, plane: Any, convention: str = DEFAULT_CONVENTION) -> np.ndarray:
    """A decrypted slice of ``plane`` turned for display (module docstring: radiological by default).

    Parameters
    ----------
    arr : np.ndarray, shape (height, width) or (height, width, C)
        The slice in the plane's pixel order (``img.decrypt(priv)`` of a :func:`hevr.render_slice`).
    plane : hevr.Plane or dict
        Its plane (or ``plane.to_dict()``, as a frame records it in ``info["camera"]``).
    convention : {"radiological", "neurological"}

    Returns
    -------
    np.ndarray
        A view of ``arr``: flipped (and transposed for a plane whose columns run vertically).

    Examples
    --------
    >>> from hevr.rendering.geometry.plane import Plane
    >>> vol = np.arange(24.0).reshape(4, 3, 2)                    # z, y, x
    >>> shown = orient_slice(vol[:, 1, :], Plane.coronal(vol.shape, 1))
    >>> bool((shown[0] == vol[-1, 1, ::-1]).all())                # top row: the top layer (superior)
    True
    """
    a = np.asarray(arr)
    if a.ndim not in (2, 3):
        raise ParameterError(f"arr: expected shape (H, W) or (H, W, C), got {a.shape}")
    lay = slice_layout(plane, convention)
    if lay["transpose"]:
        a = a.swapaxes(0, 1)
    if lay["flip_rows"]:
        a = a[::-1]
    if lay["flip_cols"]:
        a = a[:, ::-1]
    return a


def describe_layout(plane: Any, convention: str = DEFAULT_CONVENTION) -> str:
    """One line saying how a slice of ``plane`` is shown (the CLI's banners).

    Examples
    --------
    >>> from hevr.rendering.geometry.plane import Plane
    >>> describe_layout(Plane.axial((4, 3, 2), 1))
    "axial slice, radiological convention: anterior at the top, the patient's right on the left"
    """
    lay = slice_layout(plane, convention)
    return f"{lay['kind']} slice, {lay['convention']} convention: {lay['top']} at the top, {lay['left']} on the left"
