"""Array-API building blocks of the product plan: segmented reductions, bit counts, placement.

The plan (:func:`hevr.rendering.pipeline.kernel.plan_products`) works on CSR rows: contiguous segments
``[start, stop)`` of a pair array. numpy has segmented reductions (``ufunc.reduceat``) and
scattered updates (``ufunc.at``); the array API standard, which the plan is written against so
that it runs on CuPy as on numpy, has neither. This module builds them from what the standard
has, exactly (integers only, so every namespace gives the same bits):

* segment sums from one cumulative sum: ``Σ x[s:e] = C[e] − C[s]`` with ``C`` the inclusive
  prefix sums starting at 0 (unsigned sums wrap modulo 2^64 the same way on both sides);
* segment maxima of non-negative integers by deciding their bits from the top: with ``m`` the
  bits decided so far, bit ``b`` of a segment's maximum is set iff the segment holds an
  element ``>= m | 2^b`` — one segment sum of a comparison per bit (numpy's own
  ``maximum.reduceat`` is used when the namespace is numpy: the same values, faster);
* exact bit lengths and population counts of uint64 by shifts and masks (a float ``frexp``
  rounds just below 2^k for k > 53);
* ``place``: the values of some rows written into a full-length array (a scatter, as
  ``out[idx] = v`` for ascending ``idx``) by a gather through ``searchsorted``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from array_api_compat import array_namespace, is_numpy_namespace

__all__ = ["bit_length", "partition_max", "partition_sum", "place", "popcount", "segment_max", "segment_sum", "to_host"]


def to_host(a: Any) -> np.ndarray:
    """An array of any namespace as a numpy array (DLPack; numpy arrays as they are).

    >>> to_host(np.arange(3)).tolist()
    [0, 1, 2]
    """
    return a if isinstance(a, np.ndarray) else np.from_dlpack(a)


def segment_sum(x: Any, starts: Any, stops: Any) -> Any:
    """``Σ x[s:e]`` for every segment (integers; an empty segment sums to 0).

    >>> segment_sum(np.array([1, 2, 3, 4]), np.array([0, 1, 4]), np.array([2, 4, 4])).tolist()
    [3, 9, 0]
    """
    xp = array_namespace(x, starts)
    c = xp.cumulative_sum(x, include_initial=True)
    return xp.take(c, stops) - xp.take(c, starts)


def partition_sum(x: Any, offs: Any) -> Any:
    """``Σ x[offs[i]:offs[i+1]]`` (the last segment to the end) for non-empty segments that
    cover ``x`` end to end: numpy's ``add.reduceat``, else :func:`segment_sum`.

    >>> partition_sum(np.array([1, 2, 3, 4]), np.array([0, 1, 3])).tolist()
    [1, 5, 4]
    """
    xp = array_namespace(x, offs)
    if is_numpy_namespace(xp):
        return np.add.reduceat(np.asarray(x), np.asarray(offs))
    return segment_sum(x, offs, xp.concat([offs[1:], xp.asarray([x.shape[0]], dtype=offs.dtype)]))


def partition_max(x: Any, offs: Any) -> Any:
    """The largest element of ``x[offs[i]:offs[i+1]]`` (the last to the end) for non-empty
    segments covering ``x`` end to end: numpy's ``maximum.reduceat``, else :func:`segment_max`.

    >>> partition_max(np.array([3, 9, 2, 0, 5], np.uint64), np.array([0, 2, 4])).tolist()
    [9, 2, 5]
    """
    xp = array_namespace(x, offs)
    if is_numpy_namespace(xp):
        return np.maximum.reduceat(np.asarray(x), np.asarray(offs))
    return segment_max(x, offs, xp.concat([offs[1:], xp.asarray([x.shape[0]], dtype=offs.dtype)]))


def segment_max(x: Any, starts: Any, stops: Any) -> Any:
    """The largest element of every segment of non-negative integers ``x`` (0 if empty).

    >>> segment_max(np.array([3, 9, 2, 0, 5], np.uint64), np.array([0, 2, 5]), np.array([2, 5, 5])).tolist()
    [9, 5, 0]
    >>> segment_max(np.array([3, 9, 2, 0, 5], np.uint64), np.array([3, 0]), np.array([5, 1])).tolist()
    [5, 3]
    """
    xp = array_namespace(x, starts)
    out = xp.zeros(starts.shape[0], dtype=x.dtype)
    if x.shape[0] == 0 or starts.shape[0] == 0:
        return out
    lens = stops - starts  # the segments' elements, gathered end to end (they need not cover x)
    offs = xp.cumulative_sum(lens) - lens
    g = xp.take(x, xp.repeat(starts - offs, lens) + xp.arange(int(xp.sum(lens)), dtype=starts.dtype))
    if g.shape[0] == 0:
        return out
    if is_numpy_namespace(xp):  # numpy's own segmented maximum: the same values, faster
        full = np.asarray(lens) > 0
        out[full] = np.maximum.reduceat(np.asarray(g), np.asarray(offs)[full])
        return out
    top = int(xp.max(bit_length(g)))
    for b in range(top - 1, -1, -1):
        cand = out | xp.asarray(1 << b, dtype=x.dtype)
        present = segment_sum(xp.astype(g >= xp.repeat(cand, lens), xp.int64), offs, offs + lens) > 0
        out = xp.where(present, cand, out)
    return out


def bit_length(a: Any) -> Any:
    """Exact bit lengths (int64) of non-negative integers below 2^64.

    >>> bit_length(np.array([0, 1, 2, 255, 256, 2**53 - 1, 2**64 - 1], np.uint64)).tolist()
    [0, 1, 2, 8, 9, 53, 64]
    """
    xp = array_namespace(a)
    x = xp.astype(a, xp.uint64)
    bits = xp.zeros(x.shape, dtype=xp.int64)
    for s in (32, 16, 8, 4, 2, 1):
        big = (x >> s) > 0
        x = xp.where(big, x >> s, x)
        bits = bits + xp.astype(big, xp.int64) * s
    return bits + xp.astype(x > 0, xp.int64)


_M1, _M2, _M4, _H01 = 0x5555555555555555, 0x3333333333333333, 0x0F0F0F0F0F0F0F0F, 0x0101010101010101


def popcount(a: Any) -> Any:
    """Set bits (int64) of each uint64 (SWAR).

    >>> popcount(np.array([0, 1, 6, 2**64 - 1], np.uint64)).tolist()
    [0, 1, 2, 64]
    """
    xp = array_namespace(a)
    x = xp.astype(a, xp.uint64)
    with np.errstate(over="ignore"):
        x = x - ((x >> 1) & _M1)
        x = (x & _M2) + ((x >> 2) & _M2)
        x = (x + (x >> 4)) & _M4
        return xp.astype((x * _H01) >> 56, xp.int64)


def place(base: Any, idx: Any, values: Any) -> Any:
    """``base`` with ``base[idx[i]] = values[i]`` (``idx`` ascending, no repeats), by gathers.

    >>> place(np.array([0, 0, 0, 0]), np.array([1, 3]), np.array([7, 9])).tolist()
    [0, 7, 0, 9]
    """
    xp = array_namespace(base, idx)
    n = base.shape[0]
    if idx.shape[0] == 0:
        return base
    at = xp.clip(xp.searchsorted(idx, xp.arange(n, dtype=idx.dtype)), max=idx.shape[0] - 1)
    hit = xp.take(idx, at) == xp.arange(n, dtype=idx.dtype)
    return xp.where(hit, xp.take(values, at), base)
