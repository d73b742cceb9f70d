"""Encrypted floating point: encrypted mantissa, plain exponent, BASE 10 (paper §4.1).

``EncryptedNumber(public_key, ciphertext, exponent)`` stands for mantissa·10**exponent
with the mantissa encrypted. Addition is the paper's fpAdd (Alg. 1): the operand with the
larger exponent is lowered by ⊗ 10**k — an exponent is never raised, which would need a
division. Multiplication by a plain number is fpMultiply (Alg. 2, with the n − m
optimisation for negative mantissas). Division by a plain number multiplies with the
rounded reciprocal of Eq. 1.

>>> import warnings, hevr
>>> with warnings.catch_warnings():
...     warnings.simplefilter("ignore")
...     pub, priv = hevr.generate_keypair(256)
>>> x = pub.encrypt_number(3.25, exponent=-2)
>>> priv.decrypt_number(x * 0.5 + pub.encrypt_number(1))
2.625
"""

from __future__ import annotations

from collections.abc import Callable
from numbers import Integral, Real
from typing import TYPE_CHECKING

from gmpy2 import mpz

from ..errors import KeyMismatchError, ParameterError
from . import paillier as raw
from .encoding import BASE, encode, reciprocal

if TYPE_CHECKING:  # pragma: no cover
    from .keys import PublicKey

__all__ = ["EncryptedNumber"]


class EncryptedNumber:
    """A number mantissa·10**exponent whose mantissa is a Paillier ciphertext.

    Parameters
    ----------
    public_key : PublicKey
    ciphertext : int
        Encryption of the (signed, two's-complement mod n) mantissa.
    exponent : int
        Plain base-10 exponent.
    """

    __slots__ = ("public_key", "ciphertext", "exponent")
    public_key: PublicKey
    ciphertext: mpz
    exponent: int

    def __init__(self, public_key: PublicKey, ciphertext: int, exponent: int = 0) -> None:
        if not isinstance(exponent, Integral) or isinstance(exponent, bool):
            raise ParameterError(f"exponent must be an int; got {type(exponent).__name__}")
        self.public_key = public_key
        self.ciphertext = mpz(ciphertext)
        self.exponent = int(exponent)

    @classmethod
    def encrypt(
        cls, public_key: PublicKey, value: float, exponent: int | None, encrypt_int: Callable[[int], mpz]
    ) -> EncryptedNumber:
        mantissa, exp = encode(value, exponent)
        return cls(public_key, encrypt_int(mantissa), exp)

    def __repr__(self) -> str:
        return f"EncryptedNumber(exponent={self.exponent}, key={self.public_key.fingerprint[:16]}…)"

    # -- exponent handling ------------------------------------------------------------
    def decrease_exponent_to(self, new_exponent: int) -> EncryptedNumber:
        """Same value with a smaller (or equal) exponent: mantissa ⊗ 10**(e − new)."""
        if not isinstance(new_exponent, Integral):
            raise ParameterError(f"new_exponent must be an int; got {type(new_exponent).__name__}")
        if new_exponent > self.exponent:
            raise ParameterError(
                f"new_exponent must be <= the current exponent {self.exponent} (an encrypted "
                f"mantissa cannot be divided); got {new_exponent}"
            )
        if new_exponent == self.exponent:
            return self
        pk = self.public_key
        c = raw.raw_mul(self.ciphertext, BASE ** (self.exponent - int(new_exponent)), pk.n, pk.nsquare)
        return EncryptedNumber(pk, c, int(new_exponent))

    def _same_key(self, other: EncryptedNumber) -> None:
        if other.public_key != self.public_key:
            raise KeyMismatchError(
                f"cannot combine numbers under keys {self.public_key.fingerprint[:16]}… and "
                f"{other.public_key.fingerprint[:16]}…"
            )

    # -- fpAdd --------------------------------------------------------------------------
    def __add__(self, other: EncryptedNumber | float) -> EncryptedNumber:
        pk = self.public_key
        if isinstance(other, EncryptedNumber):
            self._same_key(other)
            e = min(self.exponent, other.exponent)
            a, b = self.decrease_exponent_to(e), other.decrease_exponent_to(e)
            return EncryptedNumber(pk, raw.raw_add(a.ciphertext, b.ciphertext, pk.nsquare), e)
        if isinstance(other, (Integral, Real)) and not isinstance(other, bool):
            mant, exp = encode(other)
            e = min(self.exponent, exp)
            a = self.decrease_exponent_to(e)
            mant *= BASE ** (exp - e)
            # Adding g^m keeps the sum obfuscated by a's mask; no new randomness needed.
            nude = raw.raw_encrypt_nude(raw.raw_encode_signed(mant, pk.n), pk.n, pk.nsquare)
            return EncryptedNumber(pk, raw.raw_add(a.ciphertext, nude, pk.nsquare), e)
        return NotImplemented

    __radd__ = __add__

    def __neg__(self) -> EncryptedNumber:
        return EncryptedNumber(self.public_key, raw.raw_neg(self.ciphertext, self.public_key.nsquare), self.exponent)

    def __sub__(self, other: EncryptedNumber | float) -> EncryptedNumber:
        if isinstance(other, EncryptedNumber):
            return self + (-other)
        if isinstance(other, (Integral, Real)) and not isinstance(other, bool):
            return self + (-other)
        return NotImplemented

    def __rsub__(self, other: float) -> EncryptedNumber:
        return (-self) + other

    # -- fpMultiply ------------------------------------------------------------------------
    def __mul__(self, other: float) -> EncryptedNumber:
        if isinstance(other, EncryptedNumber):
            raise ParameterError("Paillier cannot multiply two encrypted numbers; other must be plain")
        if isinstance(other, bool) or not isinstance(other, (Integral, Real)):
            return NotImplemented
        mant, exp = encode(other)
        pk = self.public_key
        if abs(mant) > pk.max_int:
            raise ParameterError(f"other is too large for this key: |mantissa| must be below n/3; got {other!r}")
        c = raw.raw_mul(self.ciphertext, mant, pk.n, pk.nsquare)
        return EncryptedNumber(pk, c, self.exponent + exp)

    __rmul__ = __mul__

    def divide(self, divisor: float, digits: int = 6) -> EncryptedNumber:
        """Divide by a plain number via its rounded reciprocal (Eq. 1).

        The reciprocal is exact to a relative error of at most 0.5·10**-digits
        (see :func:`hevr.crypto.encoding.reciprocal`).
        """
        mant, exp = reciprocal(divisor, digits)
        pk = self.public_key
        return EncryptedNumber(pk, raw.raw_mul(self.ciphertext, mant, pk.n, pk.nsquare), self.exponent + exp)

    def __truediv__(self, divisor: float) -> EncryptedNumber:
        return self.divide(divisor)
