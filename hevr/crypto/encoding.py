"""Fixed-point encoding of plain numbers as (mantissa, exponent) with BASE = 10.

A value is ``mantissa * 10**exponent``. Integers encode exactly with exponent 0; floats
encode either exactly (their shortest round-trip decimal form, like ``repr``) or rounded
half-away-from-zero at a requested exponent. Rounding is done in :class:`decimal.Decimal`
so no binary floating-point error creeps in, and the sign is always kept in the mantissa.

>>> encode(0.125)
(125, -3)
>>> encode(-3.25, exponent=-4)
(-32500, -4)
>>> decode(125, -3)
0.125
"""

from __future__ import annotations

import math
from decimal import ROUND_HALF_EVEN, ROUND_HALF_UP, Context, Decimal
from fractions import Fraction
from numbers import Integral, Real

from ..errors import ParameterError

BASE = 10

__all__ = ["BASE", "encode", "decode", "decode_exact", "reciprocal"]

_CTX = Context(prec=10_000, rounding=ROUND_HALF_EVEN)


def _check_finite(value: float, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (Integral, Real)):
        raise ParameterError(f"{name} must be an int or float; got {type(value).__name__}")
    if not isinstance(value, Integral) and not math.isfinite(float(value)):
        raise ParameterError(f"{name} must be finite; got {value!r}")


def encode(value: float, exponent: int | None = None) -> tuple[int, int]:
    """Encode ``value`` as ``(mantissa, exponent)`` with ``value ≈ mantissa * 10**exponent``.

    Parameters
    ----------
    value : int or float
        The plain number. NaN and infinities are rejected.
    exponent : int, optional
        Fix the exponent (round half away from zero). When omitted, integers use
        exponent 0 and floats their exact shortest decimal representation.

    Returns
    -------
    tuple of (int, int)

    Examples
    --------
    >>> encode(3)
    (3, 0)
    >>> encode(1 / 3, exponent=-3)
    (333, -3)
    """
    _check_finite(value, "value")
    if exponent is None:
        if isinstance(value, Integral):
            return int(value), 0
        d = Decimal(repr(float(value)))
        sign, digits, exp_ = d.as_tuple()
        exp = int(exp_)  # d is finite: its exponent is an int, never 'n', 'N' or 'F'
        mant = int("".join(map(str, digits)) or "0")
        mant = -mant if sign else mant
        if mant == 0:
            return 0, 0
        while mant % 10 == 0:
            mant //= 10
            exp += 1
        return mant, int(exp)
    if not isinstance(exponent, Integral):
        raise ParameterError(f"exponent must be an int; got {type(exponent).__name__}")
    exponent = int(exponent)
    if isinstance(value, Integral) and exponent <= 0:
        return int(value) * BASE ** (-exponent), exponent
    # The exact binary value (not its repr), so the error is at most half a unit of 10**exponent.
    d = Decimal(float(value)) if not isinstance(value, Integral) else Decimal(int(value))
    scaled = d.scaleb(-exponent, _CTX).quantize(Decimal(1), rounding=ROUND_HALF_UP, context=_CTX)
    return int(scaled), exponent


def decode_exact(mantissa: int, exponent: int) -> Fraction:
    """Exact rational value of ``mantissa * 10**exponent``."""
    return Fraction(int(mantissa)) * Fraction(BASE) ** int(exponent)


def decode(mantissa: int, exponent: int) -> float:
    """``mantissa * 10**exponent`` as the nearest float (no overflow for huge mantissas)."""
    return float(decode_exact(mantissa, exponent))


def reciprocal(divisor: float, digits: int) -> tuple[int, int]:
    """Rounded reciprocal of Eq. 1 with relative error at most 0.5·10**-digits.

    Returns ``(round(10**g / divisor), -g)`` where g = digits + (number of integer
    digits of |divisor|), so that the reciprocal mantissa itself carries ``digits``
    significant digits whatever the size of the divisor.

    >>> reciprocal(3, 4)
    (33333, -5)
    """
    _check_finite(divisor, "divisor")
    if divisor == 0:
        raise ParameterError("divisor must be non-zero; got 0")
    if not isinstance(digits, Integral) or digits < 0:
        raise ParameterError(f"digits must be a non-negative int; got {digits!r}")
    frac = Fraction(divisor) if isinstance(divisor, Integral) else Fraction(Decimal(repr(float(divisor))))
    int_digits = max(0, len(str(abs(frac.numerator // frac.denominator))) if abs(frac) >= 1 else 0)
    g = int(digits) + int_digits
    scaled = Fraction(BASE**g) / frac
    # round half away from zero
    mant = int(abs(scaled) + Fraction(1, 2))
    return (-mant if scaled < 0 else mant), -g
