"""Checks of voxel data where it enters hevr: the voxel dtype, the volume array (3-D, not empty,
thick enough for rays), its values' range (finite) and a density normalisation range.

Each checker returns what it was given normalised, or raises :class:`hevr.ParameterError` (or
the ``error`` class a loader passes) in the style ``"name: expected X, got Y"``, as the checks of
:mod:`hevr.core.validate` do.

>>> check_value_range([0, 255])
(0.0, 255.0)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ParameterError

__all__ = ["MAX_VALUE", "check_data_range", "check_dtype", "check_value_range", "check_volume"]

# Largest |value| of a value range (check_value_range): renders stay finite in float64.
MAX_VALUE = 1e100

# Voxel dtype kinds by letter (numpy's dtype.kind), in the order a message lists them.
_KIND_NAMES = {"b": "bool", "i": "integer", "u": "integer", "f": "floating-point"}


def _kinds_text(kinds: str) -> str:
    names = list(dict.fromkeys(_KIND_NAMES[k] for k in kinds))
    return ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else names[0]


def check_dtype(dtype: Any, name: str = "dtype", *, kinds: str = "uif") -> np.dtype:
    """A voxel type: a numpy dtype whose kind is one of ``kinds``, at most 8 bytes wide.

    Examples
    --------
    >>> check_dtype("uint16")
    dtype('uint16')
    >>> check_dtype(complex)
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: dtype: expected an integer or floating-point type, got <class 'complex'>
    """
    try:
        out = np.dtype(dtype)
    except (TypeError, ValueError):
        out = None
    if out is None or out.kind not in kinds or out.itemsize > 8:
        what = _kinds_text(kinds)
        raise ParameterError(f"{name}: expected {'an' if what[0] in 'aeiou' else 'a'} {what} type, got {dtype!r}")
    return out


def check_volume(
    vol: Any, name: str = "vol", *, kinds: str = "biuf", error: type[Exception] = ParameterError, thick: bool = False
) -> Any:
    """A non-empty 3-D voxel array whose dtype kind is one of ``kinds`` (at most 8 bytes);
    with ``thick=True`` (a scan read from a file, before it is encrypted) at least 2 voxels along
    every axis: rays are clipped to the box of the voxel centres, which a single slice leaves
    without thickness, so every frame of it would be empty.

    Anything with ``.shape`` and ``.dtype`` (numpy, memmap, dask, zarr) is returned as it
    is, so a lazy array stays lazy; anything else goes through :func:`numpy.asarray`. The
    values are not looked at (see :func:`check_data_range`). ``error`` is the class raised:
    loaders pass :class:`hevr.VolumeFormatError` and the file name as ``name``.

    Examples
    --------
    >>> check_volume(np.zeros((2, 3, 4), np.uint8)).shape
    (2, 3, 4)
    >>> check_volume([[1, 2]])
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: vol: expected a 3-D volume, got a 2-D array of shape (1, 2)
    >>> check_volume(np.zeros((1, 3, 4)), thick=True)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: vol: expected a volume at least 2 voxels thick along every axis (...), got 1 slice ...
    """
    if not hasattr(vol, "shape") or not hasattr(vol, "dtype"):
        vol = np.asarray(vol)
    shape, dtype = tuple(vol.shape), np.dtype(vol.dtype)
    if len(shape) != 3:
        raise error(f"{name}: expected a 3-D volume, got a {len(shape)}-D array of shape {shape}")
    if dtype.kind not in kinds or dtype.itemsize > 8:
        raise error(f"{name}: expected {_kinds_text(kinds)} voxels, got dtype {dtype}")
    if 0 in shape:
        raise error(f"{name}: expected a non-empty volume, got shape {shape}")
    if thick and min(shape) < 2:
        nz, ny, nx = shape
        got = f"{nz} slice of {nx}x{ny} voxels" if nz == 1 else f"{nx}x{ny}x{nz} voxels"
        raise error(
            f"{name}: expected a volume at least 2 voxels thick along every axis (a single slice has no "
            f"thickness for the rays to cross: every frame would be empty), got {got} (shape {shape})"
        )
    return vol


def check_data_range(lo: Any, hi: Any, name: str = "vol") -> tuple[float, float]:
    """The data range (min, max) of a volume's values, which must both be finite.

    NaN propagates through min and max, so this one test also finds NaN voxels.

    Examples
    --------
    >>> check_data_range(np.uint8(0), 2.5)
    (0.0, 2.5)
    >>> check_data_range(float("nan"), 1.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: vol: expected finite values, got NaN or infinity (min nan, max 1.0); give NaN ...
    """
    lo, hi = float(lo), float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ParameterError(
            f"{name}: expected finite values, got NaN or infinity (min {lo}, max {hi}); give NaN "
            "voxels a value first (np.nan_to_num(vol, nan=VALUE); hevr encrypt --nan-as VALUE)"
        )
    return lo, hi


def check_value_range(value_range: Any, name: str = "value_range") -> tuple[float, float]:
    """A density normalisation range (lo, hi): two finite numbers with hi > lo and
    ``|lo|, |hi| <= MAX_VALUE`` (1e100), as floats.

    The bound keeps every float step of a render finite: the width ``hi - lo``, the stored
    mantissas ``value·10^digits`` (up to 10^30, times 10^3 per pyramid level), sums over up
    to 2^53 samples and their squares. 1e100 is far beyond any float32 value (3.4e38) and any
    physical quantity a scan holds.

    Examples
    --------
    >>> check_value_range([0, 255])
    (0.0, 255.0)
    >>> check_value_range((5, 1))
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: value_range: expected finite (lo, hi) with hi > lo, got (5, 1)
    >>> check_value_range((-1e308, 1e308))
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: value_range: expected (lo, hi) with |lo|, |hi| <= 1e+100, got (-1e+308, 1e+308)
    """
    try:
        lo, hi = (float(x) for x in value_range)
    except OverflowError:  # an int beyond float64 (never str() it: 4300+ digits raise ValueError)
        raise ParameterError(
            f"{name}: expected (lo, hi) with |lo|, |hi| <= {MAX_VALUE:g}, got a number beyond float64"
        ) from None
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected two numbers (lo, hi), got {value_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise ParameterError(f"{name}: expected finite (lo, hi) with hi > lo, got {value_range!r}")
    if max(abs(lo), abs(hi)) > MAX_VALUE:
        raise ParameterError(f"{name}: expected (lo, hi) with |lo|, |hi| <= {MAX_VALUE:g}, got ({lo:g}, {hi:g})")
    return lo, hi
