"""Raw Paillier arithmetic on bare integers (g = n + 1).

The ``raw_`` functions take and return plain integers (``gmpy2.mpz``); they know nothing
about encodings, exponents or keys. This mirrors python-paillier's ``raw_encrypt`` /
``raw_add`` / ``raw_multiply`` layer: the key classes and :class:`hevr.EncryptedNumber`
are thin wrappers around these.

Plaintexts live in Z_n. Signed values use the two's-complement convention of the paper
(§4.1): v < 0 is represented by v + n. Values in [0, n//3) are non-negative, values in
(n - n//3, n) are negative, and the middle third is an overflow band.

>>> from gmpy2 import mpz
>>> n = mpz(11 * 13); n2 = n * n
>>> c = raw_encrypt_nude(5, n, n2)
>>> int(raw_add(c, raw_encrypt_nude(7, n, n2), n2)) == int(raw_encrypt_nude(12, n, n2))
True
"""

from __future__ import annotations

import hashlib
import os
from concurrent.futures import ThreadPoolExecutor

import gmpy2
from gmpy2 import mpz

from ..errors import ParameterError, PlaintextOverflowError
from .primes import is_probable_prime

__all__ = [
    "raw_encrypt_nude",
    "raw_obfuscate",
    "raw_add",
    "raw_neg",
    "raw_sub",
    "raw_mul",
    "raw_crt_h",
    "raw_decrypt_crt",
    "raw_decrypt_crt_list",
    "raw_decode_signed",
    "raw_encode_signed",
    "max_int",
    "fingerprint",
    "factor_problem",
]


def fingerprint(n: int) -> str:
    """The key's identity: hex SHA-256 of n as big-endian bytes of length ceil(bits(n)/8).

    >>> fingerprint(143)[:16]
    '5e37305c587caf07'
    """
    n = int(n)
    return hashlib.sha256(n.to_bytes((n.bit_length() + 7) // 8, "big")).hexdigest()


def max_int(n: int) -> int:
    """Largest magnitude a signed plaintext may have under modulus ``n`` (n // 3 - 1)."""
    return int(n) // 3 - 1


def raw_encode_signed(value: int, n: mpz) -> mpz:
    """Map a signed integer with |value| < n // 3 to Z_n (two's complement mod n)."""
    v = mpz(value)
    if abs(v) > n // 3 - 1:
        raise PlaintextOverflowError(
            f"plaintext magnitude must be below n // 3 for a {int(n).bit_length()}-bit key; "
            f"got a {int(abs(v)).bit_length()}-bit value (use a larger key or fewer digits)"
        )
    return v % n


def raw_decode_signed(m: mpz, n: mpz) -> mpz:
    """Inverse of :func:`raw_encode_signed`; the middle third of Z_n is an overflow."""
    third = n // 3
    if m < third:
        return mpz(m)
    if m > n - third:
        return mpz(m) - n
    raise PlaintextOverflowError(
        "decrypted value lies in the overflow band [n/3, 2n/3]: a homomorphic result "
        "exceeded the plaintext range (use a larger key or fewer digits)"
    )


def raw_encrypt_nude(m: int, n: mpz, nsquare: mpz) -> mpz:
    """g^m mod n² for g = n + 1, which is 1 + m·n (no obfuscation, not secure alone)."""
    return (1 + mpz(m) * n) % nsquare


def raw_obfuscate(c: mpz, mask: mpz, nsquare: mpz) -> mpz:
    """Multiply a ciphertext by an n-th residue ``mask`` = r^n mod n²."""
    return c * mask % nsquare


def raw_add(c1: mpz, c2: mpz, nsquare: mpz) -> mpz:
    """⊕: Dec(c1·c2 mod n²) = m1 + m2 (mod n)."""
    return c1 * c2 % nsquare


def raw_neg(c: mpz, nsquare: mpz) -> mpz:
    """Additive inverse: c^-1 mod n² decrypts to -m (mod n)."""
    return gmpy2.invert(c, nsquare)


def raw_sub(c1: mpz, c2: mpz, nsquare: mpz) -> mpz:
    """Dec(c1 · c2^-1) = m1 - m2 (mod n)."""
    return c1 * gmpy2.invert(c2, nsquare) % nsquare


def raw_mul(c: mpz, k: int, n: mpz, nsquare: mpz) -> mpz:
    """⊗ by a plain integer ``k`` (paper Alg. 2, with the n - k optimisation).

    ``k`` may be negative or given as a residue mod n. When n - k is small (k encodes a
    negative number) we raise c^-1 to n - k instead of c to k: same result, far shorter
    exponent.
    """
    k = mpz(k) % n
    if k == 0:
        return mpz(1)
    neg = n - k
    if neg < k:
        return gmpy2.powmod(gmpy2.invert(c, nsquare), neg, nsquare)
    if k == 1:
        return mpz(c)
    return gmpy2.powmod(c, k, nsquare)


def factor_problem(n: int, p: int, q: int) -> str | None:
    """What is wrong with ``p`` and ``q`` as the secret factors of ``n``, or None if nothing.

    Checks p·q = n, p ≠ q, half the bits of n each, primality and gcd(n, (p-1)(q-1)) = 1. The
    answer never quotes p or q (they are secret).

    >>> factor_problem(11 * 13, 11, 13) is None
    True
    >>> factor_problem(9 * 15, 9, 15)
    'p or q is not prime'
    """
    n, p, q = mpz(n), mpz(p), mpz(q)
    half = n.bit_length() // 2
    if p * q != n:
        return "p·q does not equal n (file tampered with?)"
    if p == q:
        return "p and q must be distinct"
    if p.bit_length() != half or q.bit_length() != half:
        return f"p and q must each have {half} bits"
    if not (is_probable_prime(p) and is_probable_prime(q)):
        return "p or q is not prime"
    if gmpy2.gcd(n, (p - 1) * (q - 1)) != 1:
        return "gcd(n, (p-1)(q-1)) must be 1"
    return None


def raw_crt_h(x: mpz, xsquare: mpz, g: mpz) -> mpz:
    """The CRT constant h_x = L_x(g^(x-1) mod x²)^-1 mod x of a prime factor x of n, L_x(u) = (u - 1) / x.

    For g = n + 1, g^(x-1) = 1 + (x-1)·n mod x², so h_x = ((x-1)·n/x)^-1 mod x:

    >>> int(raw_crt_h(mpz(11), mpz(121), mpz(11 * 13 + 1))) == int(gmpy2.invert(10 * 13, 11))
    True
    """
    lx = (gmpy2.powmod(g, x - 1, xsquare) - 1) // x
    return mpz(gmpy2.invert(lx, x))


def raw_decrypt_crt(c: mpz, p: mpz, q: mpz, psquare: mpz, qsquare: mpz, hp: mpz, hq: mpz, p_inv_q: mpz) -> mpz:
    """CRT decryption (supplementary Alg. "Decrypt"): returns m in [0, n)."""
    if c <= 0:
        raise ParameterError("ciphertext must be a positive integer below n²; got a non-positive value")
    mp = (gmpy2.powmod(c, p - 1, psquare) - 1) // p * hp % p
    mq = (gmpy2.powmod(c, q - 1, qsquare) - 1) // q * hq % q
    return mp + ((mq - mp) * p_inv_q % q) * p


# Ciphertexts per thread below which a batch decrypts on one thread (a thread's start costs ~0.1 ms,
# one 2048-bit CRT decryption ~2 ms).
_PER_THREAD = 8


def raw_decrypt_crt_list(
    cs: list, p: mpz, q: mpz, psquare: mpz, qsquare: mpz, hp: mpz, hq: mpz, p_inv_q: mpz, threads: int | None = None
) -> list:
    """:func:`raw_decrypt_crt` of every ciphertext of ``cs`` (positive, checked by the caller): the
    same numbers, with the two exponentiations of all of them done by ``gmpy2.powmod_base_list``,
    which releases the GIL, on up to ``threads`` threads (default: the CPUs, at most 8).

    >>> from gmpy2 import mpz
    >>> p, q = mpz(11), mpz(13); n = p * q
    >>> hp, hq = gmpy2.invert(p - 1, p), gmpy2.invert(q - 1, q)   # L_p(g^(p-1)) = p - 1 for g = n + 1
    >>> args = (p, q, p * p, q * q, hp, hq, gmpy2.invert(p, q))
    >>> cs = [raw_encrypt_nude(m, n, n * n) for m in (0, 5, 77)]
    >>> [int(m) for m in raw_decrypt_crt_list(cs, *args, threads=2)] == [int(raw_decrypt_crt(c, *args)) for c in cs]
    True
    """
    cs = list(cs)
    threads = max(1, min(os.cpu_count() or 1, 8) if threads is None else int(threads))
    threads = min(threads, max(1, len(cs) // _PER_THREAD))
    xp = _powmod_list(cs, p - 1, psquare, threads)
    xq = _powmod_list(cs, q - 1, qsquare, threads)
    out = []
    for a, b in zip(xp, xq):
        mp = (a - 1) // p * hp % p
        mq = (b - 1) // q * hq % q
        out.append(mp + ((mq - mp) * p_inv_q % q) * p)
    return out


def _powmod_list(bases: list, e: mpz, m: mpz, threads: int) -> list:
    """``[b^e mod m for b in bases]`` in ``threads`` contiguous chunks, each one ``powmod_base_list``."""
    if threads <= 1:
        return gmpy2.powmod_base_list(bases, e, m)
    step = -(-len(bases) // threads)
    chunks = [bases[i : i + step] for i in range(0, len(bases), step)]
    with ThreadPoolExecutor(len(chunks)) as pool:
        parts = list(pool.map(lambda chunk: gmpy2.powmod_base_list(chunk, e, m), chunks))
    return [x for part in parts for x in part]
