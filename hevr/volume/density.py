"""Density normalisation and the paper's density-to-vector encoding (Alg. 4).

``encodeDensity(density, dim)`` of Mazza/Patel/Viola (TVCG 2020, Alg. 4) maps a density in
[0, 1] to a unit vector in R^dim, HSV-to-RGB style: with ``s = density*2*(dim-1)`` the
vector walks from ``e_0`` to ``e_{dim-1}``, raising component ``m+1`` linearly while
``s`` goes from ``2m`` to ``2m+1`` and lowering component ``m`` while ``s`` goes from
``2m+1`` to ``2m+2``. Dot products of two encodings peak (at 1) where the densities agree.

At ``density = 1`` Alg. 4 is already in range: ``s = 2(dim-1)``, ``f = dim - 1/2``,
``d = dim - 1``, neither branch fires, and the result is ``e_{dim-1}``. The index is
nevertheless clamped to ``dim - 1`` so that rounding can never index out of bounds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.validate import check_vector_dims
from ..core.voxels import check_data_range, check_value_range
from ..errors import ParameterError

__all__ = ["check_brick_range", "encode_density", "normalize_density", "default_value_range", "minmax"]


def encode_density(density: Any, dims: int) -> np.ndarray:
    """Encode densities in [0, 1] as unit vectors (paper Alg. 4), vectorised.

    Parameters
    ----------
    density : float or array_like
        Normalised densities in [0, 1].
    dims : int
        Vector length, >= 2.

    Returns
    -------
    np.ndarray
        float64 of shape ``density.shape + (dims,)``, each vector of unit length.

    Examples
    --------
    >>> encode_density(0.0, 3).tolist()
    [1.0, 0.0, 0.0]
    >>> encode_density([0.25, 1.0], 2).round(4).tolist()
    [[0.8944, 0.4472], [0.0, 1.0]]
    """
    dims = check_vector_dims(dims, "dims")
    d = np.asarray(density, dtype=np.float64)
    if d.size and not (np.all(d >= 0.0) and np.all(d <= 1.0)):  # also rejects NaN
        # where, never what: this also runs inside encryption tasks, whose errors reach the
        # scheduler's logs (module docstring of hevr.store.writer)
        where = tuple(int(i) for i in np.argwhere(~((d >= 0.0) & (d <= 1.0)))[0])
        raise ParameterError(f"density: expected values in [0, 1], got one outside (or NaN) at index {where}")
    s = d * 2.0 * (dims - 1)
    fs = np.floor(s)
    frac = s - fs
    f = (fs + 1.0) / 2.0
    idx = np.minimum(np.floor(f), dims - 1).astype(np.int64)
    v = np.zeros(d.shape + (dims,), dtype=np.float64)
    np.put_along_axis(v, idx[..., None], 1.0, axis=-1)
    # Odd floor(s): falling edge of the previous component; even: rising edge of the next.
    down = (idx > 0) & (idx == f)
    up = ~down & (idx + 1 < dims) & (idx < f)
    prev = np.where(down, idx - 1, idx)
    np.put_along_axis(v, prev[..., None], np.where(down, 1.0 - frac, 1.0)[..., None], axis=-1)
    nxt = np.where(up, idx + 1, idx)
    np.put_along_axis(v, nxt[..., None], np.where(up, frac, 1.0)[..., None], axis=-1)
    unit: np.ndarray = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return unit


def minmax(vol: Any, slab_bytes: int = 64 << 20) -> tuple[Any, Any]:
    """(min, max) of a numpy array or memory map in ONE pass: slab by slab along axis 0, so a
    large memory-mapped file is read once instead of once for ``min`` and once for ``max``.
    NaN propagates, as with ``np.min``/``np.max``.

    >>> minmax(np.arange(24).reshape(2, 3, 4), slab_bytes=1)
    (0, 23)
    """
    step = max(1, slab_bytes // max(1, int(np.prod(vol.shape[1:])) * vol.dtype.itemsize))
    lo = hi = None
    for k in range(0, vol.shape[0], step):
        slab = np.asarray(vol[k : k + step])
        a, b = slab.min(), slab.max()
        lo, hi = (a, b) if lo is None or hi is None else (np.minimum(lo, a), np.maximum(hi, b))
    if lo is None or hi is None:
        raise ValueError(f"minmax: expected a volume with at least one slice, got shape {vol.shape}")
    return lo.item(), hi.item()


def check_brick_range(block: np.ndarray, value_range: tuple[float, float], index: Any) -> None:
    """Refuse a plaintext brick with a value outside ``value_range`` (or NaN) inside an
    encryption task, naming the brick but no value.

    The owner's process checked the whole volume against ``value_range`` before any task ran
    (and may say the data range there); a brick that fails here changed since (a file written
    to while it was encrypted, a non-deterministic dask array). The message goes to the
    workers' and scheduler's logs, so it quotes neither the data nor a range derived from it
    — only the brick and the public ``value_range``.

    >>> check_brick_range(np.array([1.0, 2.0]), (0.0, 2.0), (0, 0, 0))
    >>> check_brick_range(np.array([1.0, 31415.9]), (0.0, 2.0), (0, 1, 0))  # doctest: +NORMALIZE_WHITESPACE
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: vol: brick (0, 1, 0): expected values inside value_range (0.0, 2.0) as checked
    before encryption, got values outside it (the input changed while it was encrypted?)
    """
    arr = np.asarray(block)
    if not arr.size:
        return
    lo, hi = arr.min(), arr.max()
    if not (value_range[0] <= lo and hi <= value_range[1]):  # NaN fails both
        raise ParameterError(
            f"vol: brick {tuple(int(i) for i in index)}: expected values inside value_range "
            f"{tuple(float(v) for v in value_range)} as checked before encryption, got values "
            "outside it (the input changed while it was encrypted?)"
        )


def normalize_density(values: Any, value_range: Any) -> np.ndarray:
    """Map raw voxel values to densities ``(v - lo)/(hi - lo)``, float64, clipped to [0, 1].

    Examples
    --------
    >>> normalize_density(np.array([0, 51, 255], dtype=np.uint8), (0, 255)).tolist()
    [0.0, 0.2, 1.0]
    """
    lo, hi = check_value_range(value_range)
    v = np.asarray(values).astype(np.float64)
    return np.clip((v - lo) / (hi - lo), 0.0, 1.0)


def default_value_range(vol: Any, data_range: Any = None) -> tuple[float, float]:
    """Default density range: integer dtypes -> the dtype's full range; floats -> (min, max).

    ``bool`` gives (0, 1). A constant float volume gives ``(v, v + 1)`` so that every
    voxel has density 0 instead of dividing by zero. This is the one default, used by
    :func:`hevr.render_plain` and :func:`hevr.encrypt_volume`.

    Parameters
    ----------
    vol : array_like
        The volume (only its dtype is read unless it is a float volume without
        ``data_range``). An array with ``.dtype`` (numpy, dask) is not converted.
    data_range : (min, max), optional
        The float volume's data range when the caller has it already (one pass fewer,
        and a lazy array stays lazy).

    Examples
    --------
    >>> default_value_range(np.zeros((2, 2, 2), dtype=np.uint8))
    (0.0, 255.0)
    >>> default_value_range(np.array([1.5, 4.0]))
    (1.5, 4.0)
    >>> default_value_range(np.zeros(3), data_range=(2.0, 2.0))
    (2.0, 3.0)
    """
    if not hasattr(vol, "dtype"):
        vol = np.asarray(vol)
    dtype = np.dtype(vol.dtype)
    if dtype == np.bool_:
        return (0.0, 1.0)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        return (float(info.min), float(info.max))
    if data_range is None:
        if vol.size == 0:
            raise ParameterError("vol: expected a non-empty array to derive value_range, got an empty one")
        data_range = globals()["minmax"](vol)
    lo, hi = check_data_range(*data_range)
    return (lo, hi) if hi > lo else (lo, lo + 1.0)
