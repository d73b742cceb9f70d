"""Numbers that several layers must agree on: the integrity margin of every decrypted
plaintext and the size limits of a render and of an image. A leaf module (it imports no
other hevr module but the validator), so the planner, the image and its file header share
one definition.

Integrity margin κ. The planner keeps κ bits of every decrypted plaintext unused and the
client checks them (docs/security.md): a corrupted ciphertext then passes with probability
below 2^-κ. κ = 64 for every key of 256 bits or more; the insecure toy keys below that
(the paper's Table 1 starts at 64 bits) keep a quarter of their bits, so they can still
render at all.

>>> integrity_bits(2048), integrity_bits(256), integrity_bits(128), integrity_bits(64)
(64, 64, 32, 16)
>>> render_limits() == (DEFAULT_MAX_PIXELS, DEFAULT_MAX_SAMPLES)
True

Float range of an output. A decrypted pixel is ``(m − offset)·10^exponent`` with m in
[0, bound], converted exactly rounded to float64; :func:`fits_float` says whether every such
value is finite, in integer arithmetic (the planner refuses a render, and the image and its
file header an exponent, for which it is not).

>>> fits_float(10**308, 0), fits_float(10**309, -1), fits_float(2, 308)
(True, True, False)
"""

from __future__ import annotations

import sys

import dask

from .validate import check_int

__all__ = [
    "FLOAT_MAX",
    "INTEGRITY_BITS",
    "fits_float",
    "integrity_bits",
    "MAX_IMAGE_PIXELS",
    "MAX_PIXELS_KEY",
    "MAX_SAMPLES_KEY",
    "DEFAULT_MAX_PIXELS",
    "DEFAULT_MAX_SAMPLES",
    "MAX_SAMPLES_CAP",
    "render_limits",
]

INTEGRITY_BITS = 64


def integrity_bits(key_bits: int) -> int:
    """κ for a modulus of ``key_bits`` bits: 64, or a quarter of a toy key's bits."""
    return min(INTEGRITY_BITS, int(key_bits) // 4)


FLOAT_MAX = int(sys.float_info.max)  # the largest finite float64, as an exact int


def fits_float(magnitude: int, exponent: int) -> bool:
    """Whether ``magnitude·10^exponent`` (magnitude >= 0) is at most the largest finite
    float64, i.e. converts to a finite float; exact, for ``|exponent|`` up to a few thousand."""
    magnitude, exponent = int(magnitude), int(exponent)
    if exponent >= 0:
        return magnitude * 10**exponent <= FLOAT_MAX
    return magnitude <= FLOAT_MAX * 10 ** (-exponent)


# Size limits: Dask config keys, defaults and the hard caps a setting may not pass.
MAX_IMAGE_PIXELS = 1 << 26  # H·W of any image, rendered or loaded (8192²): the file reader's cap too
MAX_SAMPLES_CAP = 1 << 53  # exact in float64
MAX_PIXELS_KEY = "hevr.limits.max-pixels"
MAX_SAMPLES_KEY = "hevr.limits.max-samples"
DEFAULT_MAX_PIXELS = 4096 * 4096
DEFAULT_MAX_SAMPLES = 2**31


def _limit(key: str, default: int, cap: int) -> int:
    value = dask.config.get(key, None)
    if value is None:
        return default
    if isinstance(value, str) and value.strip().isascii() and value.strip().isdigit():
        value = int(value.strip())
    elif isinstance(value, float) and value.is_integer():
        value = int(value)
    return check_int(key, value, 1, cap)


def render_limits() -> tuple[int, int]:
    """The size limits ``(max_pixels, max_samples)`` of one render.

    Read from the Dask config keys ``hevr.limits.max-pixels`` (at most 2^26, the largest
    image a ``.hevr`` file may hold) and ``hevr.limits.max-samples`` (at most 2^53); in the
    environment ``DASK_HEVR__LIMITS__MAX_PIXELS`` and ``DASK_HEVR__LIMITS__MAX_SAMPLES``;
    else :data:`DEFAULT_MAX_PIXELS` and :data:`DEFAULT_MAX_SAMPLES`.

    Examples
    --------
    >>> with dask.config.set({"hevr.limits.max-pixels": 100}):
    ...     render_limits()[0]
    100
    """
    return (
        _limit(MAX_PIXELS_KEY, DEFAULT_MAX_PIXELS, MAX_IMAGE_PIXELS),
        _limit(MAX_SAMPLES_KEY, DEFAULT_MAX_SAMPLES, MAX_SAMPLES_CAP),
    )
