"""Prime generation with a known factorisation of p - 1, and subgroup generators.

The owner-side fast encryption (:mod:`hevr.crypto.owner`) needs a generator of the cyclic group
Z_p^*, and proving that an element generates it needs every prime factor of p - 1. We
therefore generate primes p = 2·k·r + 1 with r a large random prime and k a small random
integer (factored by trial division), so p - 1 = 2·k·r is factored by construction. p - 1
keeps a large prime factor r, so Pollard's p - 1 method gains nothing; the primes are of
exactly bits/2 bits like any Paillier key. Keys generated elsewhere (e.g. python-paillier)
still work: :func:`factor_p_minus_1` factors p - 1 by trial division plus a primality test
of the cofactor when it can, and the caller falls back to an exact CRT exponentiation when
it cannot.

Randomness comes from :mod:`secrets` only.
"""

from __future__ import annotations

import secrets
from functools import lru_cache

import gmpy2
from gmpy2 import mpz

_SMALL_BOUND = 1 << 16
_MR_ROUNDS = 50


@lru_cache(maxsize=1)
def _small_primes() -> tuple[int, ...]:
    sieve = bytearray([1]) * _SMALL_BOUND
    sieve[0:2] = b"\x00\x00"
    for i in range(2, int(_SMALL_BOUND**0.5) + 1):
        if sieve[i]:
            sieve[i * i :: i] = bytearray(len(range(i * i, _SMALL_BOUND, i)))
    return tuple(i for i in range(_SMALL_BOUND) if sieve[i])


@lru_cache(maxsize=1)
def _primorial() -> mpz:
    prod = mpz(1)
    for ell in _small_primes():
        prod *= ell
    return prod


def is_probable_prime(x: int) -> bool:
    """Miller–Rabin with 50 rounds (error below 2^-100)."""
    return bool(gmpy2.is_prime(mpz(x), _MR_ROUNDS))


def _random_bits(bits: int) -> mpz:
    return mpz(secrets.randbits(bits))


def _random_range(lo: int, hi: int) -> mpz:
    """Uniform integer in [lo, hi]."""
    return mpz(lo + secrets.randbelow(hi - lo + 1))


def factor_p_minus_1(p: int) -> tuple[int, ...] | None:
    """The distinct prime factors of p - 1, or None when trial division cannot finish.

    Trial division by every prime below 2^16 (gated by a single gcd with their product),
    then the cofactor must be 1 or a probable prime.
    """
    m = mpz(p) - 1
    factors: list[int] = []
    g = gmpy2.gcd(m, _primorial())
    if g > 1:
        for ell in _small_primes():
            if g % ell == 0:
                factors.append(ell)
                while m % ell == 0:
                    m //= ell
    if m == 1:
        return tuple(factors)
    if is_probable_prime(m):
        return tuple(factors + [int(m)])
    return None


def generator_mod_p(p: int, factors: tuple[int, ...]) -> mpz:
    """A generator of Z_p^*, verified against every prime factor of p - 1.

    x generates Z_p^* iff x^((p-1)/ell) != 1 for every prime ell | p - 1. About a
    φ(p-1)/(p-1) fraction of elements qualify, so a few random tries suffice.
    """
    p = mpz(p)
    exps = [(p - 1) // ell for ell in factors]
    while True:
        x = _random_range(2, int(p) - 1)
        if all(gmpy2.powmod(x, e, p) != 1 for e in exps):
            return x


def _plain_prime(bits: int) -> tuple[mpz, tuple[int, ...]]:
    """Uniform-ish prime of exactly ``bits`` bits whose p - 1 trial division factors."""
    while True:
        cand = _random_bits(bits) | (mpz(3) << (bits - 2)) | 1
        p = gmpy2.next_prime(cand - 1) if not is_probable_prime(cand) else cand
        if p.bit_length() != bits:
            continue
        fac = factor_p_minus_1(p)
        if fac is not None:
            return p, fac


def _structured_prime(bits: int) -> tuple[mpz, tuple[int, ...]]:
    """Prime p = 2·k·r + 1 of exactly ``bits`` bits, top two bits set, r prime."""
    kbits = 20
    rbits = bits - 1 - kbits
    while True:
        r = gmpy2.next_prime(_random_bits(rbits) | (mpz(1) << (rbits - 1)))
        if r.bit_length() != rbits:
            continue
        lo = gmpy2.c_div(mpz(3) << (bits - 2), 2 * r)  # top two bits set -> n has 2*bits bits
        hi = ((mpz(1) << bits) - 2) // (2 * r)
        if lo > hi:
            continue
        for _ in range(40 * bits):
            k = _random_range(int(lo), int(hi))
            p = 2 * k * r + 1
            if is_probable_prime(p):
                fac = factor_p_minus_1(p)
                if fac is not None:  # k < 2^21, so trial division always finishes
                    return p, fac
        # extremely unlikely: pick another r


def random_prime_with_factors(bits: int) -> tuple[mpz, tuple[int, ...]]:
    """A random prime of exactly ``bits`` bits (top two bits set) and the primes dividing p - 1."""
    if bits < 8:
        raise ValueError("prime size must be at least 8 bits")
    if bits <= 48:
        return _plain_prime(bits)
    return _structured_prime(bits)
