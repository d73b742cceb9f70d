"""World coordinates a view may hold, and the volume it is placed on.

A camera's or a plane's points and directions are three finite reals of magnitude at most
:data:`MAX_COORDINATE` (:func:`vec3`), its scalars finite reals (:func:`finite_float`), and both
place themselves on a volume given as an array shape or as a volume-like object with ``shape`` and
``spacing`` (:func:`volume_geometry`). :mod:`hevr.rendering.geometry.camera` and
:mod:`hevr.rendering.geometry.plane` share these checks.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from ...core.validate import check_shape, check_spacing
from ...errors import ParameterError

__all__ = ["MAX_COORDINATE", "finite_float", "vec3", "volume_geometry"]

# Largest |coordinate| of position, focal_point and view_up, and largest distance and
# parallel_scale, in world units: the ray geometry (differences, norms, box intersections
# along rays) stays finite and keeps ~1e-4 of a unit of precision there; far beyond any scan
# (1e12 mm is 1e6 km).
MAX_COORDINATE = 1e12


def vec3(name: str, value: Any) -> tuple[float, float, float]:
    """Validate a 3-vector of finite reals and return it as a tuple of Python floats (a bool or a
    string is no coordinate, though numpy would read True and "1" as 1.0)."""
    items = value.tolist() if isinstance(value, np.ndarray) else value
    if isinstance(items, (list, tuple)) and not all(
        isinstance(x, numbers.Real) and not isinstance(x, (bool, np.bool_)) for x in items
    ):
        raise ParameterError(f"{name}: expected 3 finite numbers (x, y, z), got {value!r}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected 3 finite numbers (x, y, z), got {value!r}") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name}: expected 3 finite numbers (x, y, z), got {value!r}")
    if np.abs(arr).max() > MAX_COORDINATE:
        raise ParameterError(
            f"{name}: expected coordinates of magnitude at most {MAX_COORDINATE:g} (world units), "
            f"got {tuple(float(x) for x in arr)}"
        )
    # + 0.0 turns -0.0 into 0.0 so equal cameras have equal keys.
    return (float(arr[0]) + 0.0, float(arr[1]) + 0.0, float(arr[2]) + 0.0)


def finite_float(name: str, value: Any, expected: str) -> float:
    """``value`` as a finite Python float (not a bool); ``expected`` words the refusal."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name}: expected {expected}, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise ParameterError(f"{name}: expected {expected}, got {value!r}")
    return out + 0.0


def volume_geometry(ev_or_shape: Any, spacing: Any) -> tuple[tuple[int, int, int], tuple[float, float, float]]:
    """Extract (shape, spacing) from a shape tuple or a volume-like object (``spacing`` overrides
    the object's; default (1, 1, 1) for a shape)."""
    if hasattr(ev_or_shape, "shape") and hasattr(ev_or_shape, "spacing"):
        shape_in = ev_or_shape.shape
        if spacing is None:
            spacing = ev_or_shape.spacing
    else:
        shape_in = ev_or_shape
    shape = check_shape(shape_in, "ev_or_shape")
    sp = check_spacing((1.0, 1.0, 1.0) if spacing is None else spacing)
    return shape, sp
