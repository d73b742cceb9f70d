"""The fixed point of a store's channels, planned on the owner's machine before anything is
written (:func:`plan_channels`), and the integer mantissas of one brick (:func:`quantise_scalar`,
:func:`quantise_vector`) inside the encryption tasks.

A scalar voxel v is stored as the integer mantissa m = v (integer volumes, exact) or
m = rint(v·10^d) (float volumes, d = ``digits``, exponent −d); a vector component c ∈ [0, 1]
of the paper's k-dimensional encoding (Alg. 4) as rint(c·10^d') (d' = ``vector_digits``).
Every mantissa must stay below n/3 − 1 in magnitude (the middle band of Z_n decrypts
ambiguously), checked here against the data range, which stays with the owner: it is never
stored (only ``value_range`` is) and never quoted by a task.

>>> import numpy as np
>>> from hevr.store.metadata import ChannelInfo
>>> quantise_scalar(np.array([[[1.25, -0.5]]]), ChannelInfo(exponent=-2, digits=2))
[125, -50]
"""

from __future__ import annotations

import logging
from typing import Any

import dask
import dask.array
import numpy as np

from ..core.validate import MAX_STORE_DIGITS, check_int, check_vector_dims
from ..core.voxels import check_data_range, check_value_range
from ..errors import ParameterError
from ..volume.density import default_value_range, minmax
from .metadata import ChannelInfo

log = logging.getLogger("hevr.store.writer")

__all__ = ["data_range", "plan_channels", "quantise_scalar", "quantise_vector"]


def data_range(vol: Any) -> tuple[float, float]:
    """The finite data range (min, max) in one pass; dask arrays are reduced lazily.

    NaN propagates through min and max, so the finiteness check needs no extra pass.
    """
    if isinstance(vol, dask.array.Array):
        lo, hi = dask.compute(vol.min(), vol.max())
    else:
        lo, hi = minmax(vol)  # one pass over a large array, not two
    return check_data_range(lo, hi)


def plan_channels(
    vol: Any, key_n: int, scalar: bool, vector_dims: Any, value_range: Any, digits: Any, vector_digits: Any
) -> tuple[ChannelInfo | None, ChannelInfo | None, tuple[float, float]]:
    """The scalar and vector channels' fixed point and the value range (the gradient channel,
    when asked for, is the vector one's twin: same dims and digits)."""
    is_float = np.dtype(vol.dtype).kind == "f"
    if vector_dims is not None:
        vector_dims = check_vector_dims(vector_dims)
    if not scalar and vector_dims is None:
        raise ParameterError("scalar/vector_dims: expected at least one channel, got scalar=False and vector_dims=None")
    lo, hi = data_range(vol)
    if value_range is None:
        value_range = default_value_range(vol, (lo, hi))
        if is_float:
            log.warning(
                "value_range not given for a float volume; using the data range %s, which "
                "is then visible in the store metadata",
                value_range,
            )
    vr = check_value_range(value_range)
    if lo < vr[0] or hi > vr[1]:
        raise ParameterError(f"vol: values must lie inside value_range {vr}; got data range [{lo}, {hi}]")
    sc = vc = None
    max_int = int(key_n) // 3 - 1
    if scalar:
        if is_float:
            d = check_int("digits", 3 if digits is None else digits, 0, MAX_STORE_DIGITS)
            if max(abs(lo), abs(hi)) * 10.0**d >= max_int:
                raise ParameterError(f"digits: {d} digits overflow a {int(key_n).bit_length()}-bit key; use fewer")
            sc = ChannelInfo(exponent=-d, digits=d)
        else:
            if digits is not None:
                raise ParameterError("digits: integer volumes are stored exactly; digits applies to float volumes only")
            top = max(abs(int(lo)), abs(int(hi)))
            if top >= max_int:
                raise ParameterError(
                    f"vol: values up to {top} do not fit a "
                    f"{int(key_n).bit_length()}-bit key (|value| must stay below n/3); use a larger key"
                )
            sc = ChannelInfo(exponent=0)
    if vector_dims is not None:
        vd = check_int("vector_digits", vector_digits, 1, 12)
        if 10**vd >= max_int:
            raise ParameterError(f"vector_digits: {vd} digits overflow a {int(key_n).bit_length()}-bit key; use fewer")
        vc = ChannelInfo(exponent=-vd, digits=vd, dims=vector_dims)
    return sc, vc, vr


def quantise_scalar(block: np.ndarray, info: ChannelInfo) -> list[int]:
    """Mantissas of one brick as Python ints, converted in one vectorised step."""
    if info.digits is None:
        # uint64 values above 2^63 do not fit int64; tolist() on the original dtype is exact
        return block.ravel().tolist() if block.dtype == np.uint64 else block.astype(np.int64).ravel().tolist()
    scaled = np.rint(block.astype(np.float64).ravel() * 10.0**info.digits)
    if scaled.size and np.abs(scaled).max() < 2.0**62:
        return scaled.astype(np.int64).tolist()
    return [int(v) for v in scaled]  # mantissas beyond int64 (large keys, many digits)


def quantise_vector(enc: np.ndarray, info: ChannelInfo) -> np.ndarray:
    """(k, voxels) non-negative integer mantissas of a (..., k) field with components in [0, 1]:
    the Alg. 4 encoding (vector) or g·e(d) (gradient)."""
    digits, dims = info.digits_dims()
    q = np.rint(enc * 10.0**digits).astype(np.int64)
    return q.reshape(-1, dims).T
