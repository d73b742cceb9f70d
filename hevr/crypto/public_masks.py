"""Public-key encryption with a fixed base and short exponents (Damgård–Jurik–Nielsen).

Textbook Paillier masks every ciphertext with r^n mod n², r uniform in Z_n^*: a full
exponentiation modulo n² with a bits(n)-bit exponent, about 2.4·bits(n) multiplications of
2·bits(n)-bit numbers — 14 ms at 2048 bits, the whole cost of encrypting with the public key.

Damgård, Jurik and Nielsen ("A generalization of Paillier's public-key system with
applications to electronic voting", Int. J. Inf. Secur. 9, 2010, §4.2) replace it by h^s with

* ``h = x^n mod n²`` for one x uniform in Z_n^* (from :mod:`secrets`), drawn once per key
  and process: a uniformly random n-th residue, fixed;
* ``s`` uniform in [0, 2^⌈bits(n)/2⌉), drawn from :mod:`secrets` for every ciphertext.

h^s = (x^s)^n is an n-th residue, so ``(1 + m·n)·h^s`` decrypts to m exactly like a textbook
ciphertext (the tests decrypt random values of every sign). With a fixed base, h^s comes from a
window table (``G^(d·2^(w·i))``, :class:`hevr.crypto.owner._FixedBase`) in ⌈bits(s)/w⌉
multiplications: 128 instead of ~4,900 at 2048 bits (w = 8; 16.8 MB of table per key and
process, built in ~0.2 s).

Assumption
----------
The masks are no longer uniform over the n-th residues (the owner's path,
:mod:`hevr.crypto.owner`, still is, exactly). Semantic security rests on the decisional
composite residuosity assumption *and* on the short-exponent assumption of DJN: for a random
n-th residue h, h^s with s uniform below 2^⌈bits(n)/2⌉ cannot be told from a uniform n-th
residue. Exponents of half the modulus length are DJN's choice, well above the 2·κ bits (224
for the 112-bit security of a 2048-bit key) that the best known attacks on short exponents
(baby-step giant-step, Pollard's λ: ~2^(bits(s)/2) work) would need.
"""

from __future__ import annotations

import secrets
import threading

import gmpy2
from gmpy2 import mpz

from .owner import _FixedBase

__all__ = ["exponent_bits", "public_mask"]

_TABLES: dict[int, tuple[int, _FixedBase]] = {}  # n -> (exponent bits, table of h = x^n mod n²)
_LOCK = threading.Lock()
_KEEP = 4  # keys whose tables a process keeps (a table is ~17 MB at 2048 bits)


def exponent_bits(n: int) -> int:
    """Bits of the short exponent s: ⌈bits(n)/2⌉.

    >>> exponent_bits(2 ** 2047 + 1)
    1024
    """
    return (int(n).bit_length() + 1) // 2


def _window(n: int) -> int:
    # 2^w entries of bits(n²) per row: w = 8 costs 16.8 MB at 2048 bits (128 products per mask),
    # w = 6 keeps a 3072-bit key at 12.6 MB (256 products).
    return 8 if int(n).bit_length() <= 2048 else 6


def _table(n: mpz, nsquare: mpz) -> tuple[int, _FixedBase]:
    key = int(n)
    with _LOCK:
        found = _TABLES.get(key)
    if found is not None:
        return found
    while True:
        x = mpz(secrets.randbelow(key))
        if x > 1 and gmpy2.gcd(x, n) == 1:
            break
    bits = exponent_bits(key)
    table = (bits, _FixedBase(gmpy2.powmod(x, n, nsquare), nsquare, (mpz(1) << bits) - 1, window=_window(key)))
    with _LOCK:
        if len(_TABLES) >= _KEEP:
            _TABLES.pop(next(iter(_TABLES)))
        return _TABLES.setdefault(key, table)


def public_mask(n: mpz, nsquare: mpz) -> mpz:
    """A fresh mask h^s mod n² for the public key n (module docstring).

    >>> n = mpz(293 * 433)
    >>> m = public_mask(n, n * n)
    >>> gmpy2.powmod(m, 292 * 432, n * n) == 1   # an n-th residue: its order divides φ(n)
    True
    """
    bits, table = _table(n, nsquare)
    return table.pow(secrets.randbits(bits))
