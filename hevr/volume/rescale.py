"""Stored values to real values: ``raw * slope + intercept`` as DICOM and NIfTI define it,
keeping integers integer (Hounsfield units stay exact int16) when the factors allow."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["rescale"]


def rescale(raw: np.ndarray, slope: Any, inter: Any) -> np.ndarray:
    """``raw * slope + inter`` (per slice along axis 0 for arrays), integer-preserving.

    With integral factors the result is the smallest signed type from int16 upwards
    that holds every intermediate, so Hounsfield units stay exact int16; otherwise float32
    (float64 for float64 input, or when the values leave float32's range). Integral factors
    too large for int64 (a hostile ``RescaleSlope`` of 1e300) give float64, never overflow.

    >>> rescale(np.array([[[2]]], np.int16), 1e300, 0).dtype
    dtype('float64')
    >>> rescale(np.array([[[2]]], np.int16), 3, -1024).tolist()
    [[[-1018]]]
    """
    slope = np.asarray(slope, np.float64).reshape((-1,) + (1,) * (raw.ndim - 1))
    inter = np.asarray(inter, np.float64).reshape((-1,) + (1,) * (raw.ndim - 1))
    if (slope == 1).all() and (inter == 0).all():
        return raw
    if raw.dtype.kind not in "iu" or (slope % 1).any() or (inter % 1).any():
        return _float(raw, slope, inter)
    if slope.shape[0] > 1:  # per-slice factors: the range of each slice matters
        flat = raw.reshape(slope.shape[0], -1)
        lo, hi = flat.min(axis=1).astype(np.float64), flat.max(axis=1).astype(np.float64)
    else:  # no reshape: it would copy a transposed/Fortran-ordered memmap
        lo, hi = np.array([raw.min()], np.float64), np.array([raw.max()], np.float64)
    s, b = slope.ravel(), inter.ravel()
    ends = np.concatenate([lo, hi, lo * s, hi * s, lo * s + b, hi * s + b])
    target = next(
        (t for t in (np.int16, np.int32, np.int64) if np.iinfo(t).min <= ends.min() and ends.max() <= np.iinfo(t).max),
        None,
    )
    if target is None:  # beyond int64: exact integers are out of reach anyway
        return _float(raw, slope, inter, np.float64)
    out: np.ndarray = raw.astype(target)
    out *= slope.astype(target)
    out += inter.astype(target)
    return out


def _float(raw: np.ndarray, slope: np.ndarray, inter: np.ndarray, ftype: Any = None) -> np.ndarray:
    """``raw * slope + inter`` in float32, or float64 for float64 input or values beyond float32."""
    if ftype is None:
        top = max(abs(float(raw.min())), abs(float(raw.max()))) if raw.size else 0.0
        big = float(np.abs(slope).max()) * top + float(np.abs(inter).max())
        ftype = np.float64 if raw.dtype == np.float64 or big > np.finfo(np.float32).max / 2 else np.float32
    out = raw.astype(ftype)
    out *= slope.astype(ftype)
    out += inter.astype(ftype)
    return out
