"""The pixel grids of slice planes through a volume, and the checks of a plane's directions and spacing.

:meth:`Plane.axial <hevr.rendering.geometry.plane.Plane.axial>`, ``coronal`` and ``sagittal`` put an
axis-aligned grid on a layer of the array (:func:`aligned_grid`; by default the volume's own pixels),
:meth:`Plane.oblique <hevr.rendering.geometry.plane.Plane.oblique>` an orthonormal grid through a point
with a given normal (:func:`oblique_grid`); each gives the fields of a
:class:`~hevr.rendering.geometry.plane.Plane`. Conventions: :mod:`hevr.rendering.geometry.plane`.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from ...core.limits import MAX_IMAGE_PIXELS
from ...core.validate import check_int
from ...errors import ParameterError
from .coordinates import vec3, volume_geometry

__all__ = ["PARALLEL_TOL", "PlaneFields", "aligned_grid", "oblique_grid", "pixel_spacing_of", "unit"]

# |u x v| below this (unit vectors) counts as parallel.
PARALLEL_TOL = 1e-9
# A vector whose norm is this close to 1 is kept as given, so normalising is idempotent
# (from_dict(to_dict(p)) == p, bit for bit).
_UNIT_TOL = 8 * np.finfo(np.float64).eps

Vec3 = tuple[float, float, float]
# A Plane's fields in order: origin, u, v, width, height, (du, dv), slab, slab_step.
PlaneFields = tuple[Vec3, Vec3, Vec3, int, int, tuple[float, float], int, float]


def unit(name: str, value: Any) -> tuple[float, float, float]:
    """``value`` as a unit direction (x, y, z): normalised unless within rounding of unit length."""
    vec = np.asarray(vec3(name, value), dtype=np.float64)
    norm = float(np.linalg.norm(vec))
    if norm == 0.0:
        raise ParameterError(f"{name}: expected a non-zero direction (x, y, z), got {tuple(vec.tolist())}")
    if abs(norm - 1.0) > _UNIT_TOL:
        vec = vec / norm
    return (float(vec[0]) + 0.0, float(vec[1]) + 0.0, float(vec[2]) + 0.0)


def pixel_spacing_of(value: Any) -> tuple[float, float]:
    """One positive number (square pixels) or a pair (du, dv)."""
    expected = "a positive pixel spacing D or a pair (du, dv) of world units per pixel"
    vals = [value] if isinstance(value, numbers.Real) else value
    try:
        out = [float(x) for x in vals if isinstance(x, numbers.Real) and not isinstance(x, bool)]
        ok = len(out) == len(vals) and len(out) in (1, 2) and all(math.isfinite(x) and x > 0 for x in out)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if isinstance(value, (bool, str, bytes)) or not ok:
        raise ParameterError(f"pixel_spacing: expected {expected}, got {value!r}")
    return (out[0] + 0.0, out[-1] + 0.0)


def _position(name: str, value: Any, lo: float, hi: float) -> float:
    """``value`` as a real position in ``[lo, hi]`` (``name`` in the message)."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    x = float(value) if ok else math.nan
    if not (math.isfinite(x) and lo <= x <= hi):
        raise ParameterError(f"{name}: expected a position in [{lo:g}, {hi:g}], got {value!r}")
    return x


def aligned_grid(
    ev_or_shape: Any,
    spacing: Any,
    kind: int,
    index: Any,
    width: Any,
    height: Any,
    pixel_spacing: Any,
    slab: int,
    slab_step: Any,
) -> PlaneFields:
    """The fields of an axis-aligned plane; ``kind`` 0 axial (normal axis z), 1 coronal (y), 2 sagittal (x)
    (the other arguments: :meth:`Plane.axial <hevr.rendering.geometry.plane.Plane.axial>`)."""
    shape, sp = volume_geometry(ev_or_shape, spacing)
    n_world = (shape[2], shape[1], shape[0])  # voxels along x, y, z
    normal_axis, ua, va = ((2, 0, 1), (1, 0, 2), (0, 1, 2))[kind]
    name = ("k", "j", "i")[kind]
    pos = _position(name, index, 0.0, float(n_world[normal_axis] - 1)) * sp[normal_axis]
    ext = [(n_world[a] - 1) * sp[a] for a in (ua, va)]
    w, h, du, dv = _fit(ext, (sp[ua], sp[va]), width, height, pixel_spacing)
    origin = [0.0, 0.0, 0.0]
    origin[normal_axis] = pos
    origin[ua] = (ext[0] - (w - 1) * du) / 2.0
    origin[va] = (ext[1] - (h - 1) * dv) / 2.0
    u = (float(ua == 0), float(ua == 1), float(ua == 2))
    v = (float(va == 0), float(va == 1), float(va == 2))
    o = (origin[0], origin[1], origin[2])
    return o, u, v, w, h, (du, dv), slab, sp[normal_axis] if slab_step is None else slab_step


def oblique_grid(
    ev_or_shape: Any,
    center: Any,
    normal: Any,
    v: Any,
    width: int | None,
    height: int | None,
    pixel_spacing: Any,
    slab: int,
    slab_step: float | None,
    spacing: Any,
) -> PlaneFields:
    """The fields of a plane through ``center`` with the given ``normal``, the pixel grid centred on it
    (the arguments: :meth:`Plane.oblique <hevr.rendering.geometry.plane.Plane.oblique>`)."""
    shape, sp = volume_geometry(ev_or_shape, spacing)
    extent = np.array([(shape[2] - 1) * sp[0], (shape[1] - 1) * sp[1], (shape[0] - 1) * sp[2]])
    c = extent / 2.0 if center is None else np.asarray(vec3("center", center))
    n = np.asarray(unit("normal", normal))
    if v is None:
        hint = np.array([0.0, 1.0, 0.0]) if abs(n[2]) >= max(abs(n[0]), abs(n[1])) else np.array([0.0, 0.0, 1.0])
    else:
        hint = np.asarray(unit("v", v))
    vv = hint - float(np.dot(hint, n)) * n
    if float(np.linalg.norm(vv)) < PARALLEL_TOL:
        raise ParameterError(
            f"v: expected a direction not parallel to normal = {tuple(n.tolist())}, got {tuple(hint.tolist())}"
        )
    vv = vv / np.linalg.norm(vv)
    uu = np.cross(vv, n)
    d = min(sp) if pixel_spacing is None else None
    du, dv = (d, d) if d is not None else pixel_spacing_of(pixel_spacing)
    diag = float(np.linalg.norm(extent))
    w = _count(diag, du) if width is None else check_int("width", width, 1)
    h = _count(diag, dv) if height is None else check_int("height", height, 1)
    origin = c - (w - 1) / 2.0 * du * uu - (h - 1) / 2.0 * dv * vv
    return (
        _as_vec3(origin),
        _as_vec3(uu),
        _as_vec3(vv),
        w,
        h,
        (du, dv),
        slab,
        min(sp) if slab_step is None else slab_step,
    )


def _as_vec3(a: np.ndarray) -> Vec3:
    """A float64 (3,) array as a tuple of three Python floats."""
    x, y, z = a.tolist()
    return (x, y, z)


def _fit(ext: list, voxel: tuple, width: Any, height: Any, pixel_spacing: Any) -> tuple[int, int, float, float]:
    """Image size and pixel spacing of an axis-aligned plane (:func:`aligned_grid`)."""
    w = None if width is None else check_int("width", width, 1)
    h = None if height is None else check_int("height", height, 1)
    if pixel_spacing is not None:
        du, dv = pixel_spacing_of(pixel_spacing)
    elif w is None and h is None:
        du, dv = float(voxel[0]), float(voxel[1])
    else:  # square pixels that fit the extent into the given size
        fits = [e / (n - 1) for e, n in zip(ext, (w, h)) if n is not None and n > 1 and e > 0]
        du = dv = max(fits) if fits else float(min(voxel))
    if w is None:
        w = _count(ext[0], du)
    if h is None:
        h = _count(ext[1], dv)
    return w, h, du, dv


def _count(extent: float, d: float) -> int:
    """Pixels of spacing ``d`` across ``extent``, refused (naming ``pixel_spacing``) past the image cap.

    >>> _count(10.0, 0.5)
    21
    """
    n = extent / d + 1e-9
    if not math.isfinite(n) or n >= MAX_IMAGE_PIXELS:
        raise ParameterError(
            f"pixel_spacing: expected a spacing giving at most {MAX_IMAGE_PIXELS} pixels across "
            f"the volume's extent {extent:g}, got {d:g}"
        )
    return int(math.floor(n)) + 1
