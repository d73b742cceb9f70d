"""Input validation: one checker per rule, called where data enters hevr.

Each checker takes what a caller passed and returns it normalised (Python ints and floats,
tuples) or raises :class:`hevr.ParameterError` with the project's message style
``"name: expected X, got Y"``. The public entry points (:func:`hevr.encrypt_volume`,
:func:`hevr.render`, :func:`hevr.render_plain`, :func:`hevr.error_bound`,
:class:`hevr.Camera`, :func:`hevr.load_volume`, :func:`hevr.save_volume`, ...) call them
once on their arguments; the inner steps they call trust the checked values and do not
check them again. The checks of voxel data (dtype, the volume array, value ranges) are
:mod:`hevr.core.voxels`'.

>>> check_brick(32)
(32, 32, 32)
>>> check_int("tile", 0, 1, 4096)
Traceback (most recent call last):
    ...
hevr.errors.ParameterError: tile: expected an integer in [1, 4096], got 0
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import ParameterError

__all__ = [
    "MAX_BRICK_EDGE",
    "MAX_BRICK_VOXELS",
    "MAX_VECTOR_DIMS",
    "MAX_STORE_DIGITS",
    "check_bool",
    "check_brick",
    "check_brick_index",
    "check_choice",
    "check_int",
    "check_shape",
    "check_spacing",
    "check_step",
    "check_vector_dims",
    "is_decimal",
]

# Largest brick (check_brick): voxels along one axis, and voxels in all.
MAX_BRICK_EDGE = 4096
MAX_BRICK_VOXELS = 1 << 24
# Largest density encoding (check_vector_dims): the paper uses 4; every dimension is one
# more ciphertext per voxel and one more float64 per sample in the plaintext renderer.
MAX_VECTOR_DIMS = 64
# Most decimal digits a stored channel keeps (float digits=, the store metadata's exponents).
MAX_STORE_DIGITS = 30


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _int_expectation(lo: int | None, hi: int | None) -> str:
    if lo is not None and hi is not None:
        return f"an integer in [{lo}, {hi}]"
    if lo == 1:
        return "a positive integer"
    if lo == 0:
        return "a non-negative integer"
    if lo is not None:
        return f"an integer >= {lo}"
    return "an integer" if hi is None else f"an integer <= {hi}"


def is_decimal(value: Any, max_digits: int) -> bool:
    """A string of 1 to ``max_digits`` ASCII digits 0-9 (the length is checked first).

    ``str.isdigit`` and ``int`` alone also take '١٢٣' or fullwidth digits, and ``int`` of a
    huge string is slow; every big integer read from a file (key files, store metadata, image
    headers) passes this first.

    >>> is_decimal("12345", 10), is_decimal("١٢٣", 10), is_decimal("-1", 10), is_decimal("9" * 11, 10)
    (True, False, False, False)
    """
    return isinstance(value, str) and 0 < len(value) <= max_digits and value.isascii() and value.isdigit()


def check_pixel_ids(pixels: Any, width: int, height: int) -> np.ndarray:
    """Global pixel indices ``row·width + col`` as a flat int64 array in ``[0, width·height)``
    (what :meth:`hevr.Camera.rays` and :meth:`hevr.Plane.rays` accept).

    >>> check_pixel_ids([3, 0], 2, 2).tolist()
    [3, 0]
    >>> check_pixel_ids([4], 2, 2)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: pixels: expected indices in [0, 4), got 4..4
    """
    arr = np.asarray(pixels).reshape(-1)
    if arr.size and arr.dtype.kind not in "iu":
        raise ParameterError(f"pixels: expected integer pixel indices, got {arr.dtype}")
    arr = arr.astype(np.int64)
    n = width * height
    if arr.size and (arr.min() < 0 or arr.max() >= n):
        raise ParameterError(f"pixels: expected indices in [0, {n}), got {arr.min()}..{arr.max()}")
    return arr


def check_bool(name: str, value: Any) -> bool:
    """``value`` if it is True or False (numpy's bool too), as a Python bool.

    >>> check_bool("overwrite", True)
    True
    >>> check_bool("overwrite", "yes")
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: overwrite: expected True or False, got 'yes'
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def check_int(name: str, value: Any, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (not a bool) in ``[lo, hi]`` (either bound may be ``None``), as an int.

    Examples
    --------
    >>> check_int("digits", 3, 0, 9), check_int("width", 150, 1)
    (3, 150)
    >>> check_int("vector_dims", 1, 2)
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: vector_dims: expected an integer >= 2, got 1
    """
    if not _is_int(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ParameterError(f"{name}: expected {_int_expectation(lo, hi)}, got {value!r}")
    return int(value)


def check_choice(name: str, value: Any, choices: Sequence[str]) -> str:
    """One of ``choices``.

    Examples
    --------
    >>> check_choice("sampling", "cubic", ("nearest", "trilinear"))
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: sampling: expected one of nearest, trilinear, got 'cubic'
    """
    if not isinstance(value, str) or value not in choices:
        raise ParameterError(f"{name}: expected one of {', '.join(choices)}, got {value!r}")
    return value


def check_shape(shape: Any, name: str = "shape") -> tuple[int, int, int]:
    """A volume shape (nz, ny, nx) of 3 positive integers, as a tuple of ints.

    Examples
    --------
    >>> check_shape(np.array([2, 3, 4]))
    (2, 3, 4)
    >>> check_shape((2, 0, 4))
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: shape: expected 3 positive integers (nz, ny, nx), got (2, 0, 4)
    """
    try:
        out = tuple(shape)
    except TypeError:
        out = ()
    if len(out) != 3 or not all(_is_int(s) and s > 0 for s in out):
        raise ParameterError(f"{name}: expected 3 positive integers (nz, ny, nx), got {shape!r}")
    nz, ny, nx = (int(s) for s in out)
    return nz, ny, nx


def check_spacing(spacing: Any, name: str = "spacing") -> tuple[float, float, float]:
    """A world-order voxel spacing (sx, sy, sz) of 3 positive finite numbers, as floats.

    Examples
    --------
    >>> check_spacing((1, 2, 0.5))
    (1.0, 2.0, 0.5)
    >>> check_spacing("123")
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: spacing: expected 3 positive finite numbers (sx, sy, sz), got '123'
    """
    try:
        out = () if isinstance(spacing, (str, bytes)) else tuple(float(s) for s in spacing)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or not all(math.isfinite(s) and s > 0 for s in out):
        raise ParameterError(f"{name}: expected 3 positive finite numbers (sx, sy, sz), got {spacing!r}")
    return out


def check_step(step: Any, name: str = "step") -> float:
    """The sampling step along a ray: a positive finite number (world units), as a float.

    Examples
    --------
    >>> check_step(1)
    1.0
    >>> check_step(10**400)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: step: expected a positive finite number (world units), got an integer of 401 digits
    """
    if isinstance(step, bool) or not isinstance(step, numbers.Real):
        raise ParameterError(f"{name}: expected a positive finite number (world units), got {step!r}")
    try:
        value = float(step)
    except OverflowError:
        raise ParameterError(
            f"{name}: expected a positive finite number (world units), got an integer of "
            f"{len(str(abs(math.trunc(step))))} digits"
        ) from None
    if not math.isfinite(value) or value <= 0:
        raise ParameterError(f"{name}: expected a positive finite number (world units), got {step!r}")
    return value


def check_brick(brick: Any, name: str = "brick", *, shape: Any = None) -> tuple[int, int, int]:
    """A brick shape in array order: one positive int (a cube) or 3 positive ints.

    A brick is one Zarr chunk of ciphertexts and the unit of work of one Dask task, so it
    must stay small enough to hold in a worker's memory: at most :data:`MAX_BRICK_EDGE`
    (4096) voxels along an axis and :data:`MAX_BRICK_VOXELS` (2^24 = 256³) voxels in all —
    already 8 GiB of 2048-bit ciphertexts per channel, while useful bricks hold 10³–64³.
    With ``shape`` (the volume's), each axis is then clipped to the volume's size, so a
    brick bigger than the volume (up to the caps) means "one brick along that axis" and the
    Zarr chunk is never bigger than the volume.

    Examples
    --------
    >>> check_brick((2, 3, 4))
    (2, 3, 4)
    >>> check_brick(1000, shape=(20, 30, 40))
    (20, 30, 40)
    >>> check_brick(0)
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: brick: expected a positive int or 3 positive ints (B0, B1, B2), got 0
    >>> check_brick(10**9)
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: brick: expected at most 4096 voxels per axis, got 1000000000
    """
    try:
        out = (brick,) * 3 if _is_int(brick) else tuple(brick)
    except TypeError:
        out = ()
    if len(out) != 3 or not all(_is_int(b) and b > 0 for b in out):
        raise ParameterError(f"{name}: expected a positive int or 3 positive ints (B0, B1, B2), got {brick!r}")
    if max(out) > MAX_BRICK_EDGE:
        raise ParameterError(f"{name}: expected at most {MAX_BRICK_EDGE} voxels per axis, got {brick!r}")
    if shape is not None:
        out = tuple(min(b, s) for b, s in zip(out, check_shape(shape)))
    if math.prod(out) > MAX_BRICK_VOXELS:
        raise ParameterError(
            f"{name}: expected at most {MAX_BRICK_VOXELS} voxels per brick (2^24, e.g. 256^3), "
            f"got {tuple(int(b) for b in out)} = {math.prod(out)} voxels"
        )
    b0, b1, b2 = (int(b) for b in out)
    return b0, b1, b2


def check_vector_dims(dims: Any, name: str = "vector_dims") -> int:
    """The length k of the density encoding: an integer in [2, :data:`MAX_VECTOR_DIMS`].

    Examples
    --------
    >>> check_vector_dims(4)
    4
    >>> check_vector_dims(10**12)
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: vector_dims: expected an integer in [2, 64], got 1000000000000
    """
    return check_int(name, dims, 2, MAX_VECTOR_DIMS)


def check_brick_index(index: Any, grid: Sequence[int], name: str = "brick_index") -> tuple[int, int, int]:
    """A brick index (bz, by, bx) inside the brick grid, as a tuple of ints.

    Examples
    --------
    >>> check_brick_index([1, 0, 2], (2, 2, 3))
    (1, 0, 2)
    >>> check_brick_index((2, 0, 0), (2, 2, 3))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: brick_index: expected a brick index (bz, by, bx) inside the grid ..., got (2, 0, 0)
    """
    try:
        out = tuple(int(i) for i in index)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or not all(0 <= i < g for i, g in zip(out, grid)):
        raise ParameterError(
            f"{name}: expected a brick index (bz, by, bx) inside the grid {tuple(grid)}, got {index!r}"
        )
    return out
