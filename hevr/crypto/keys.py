"""Paillier keys (g = n + 1): generation, and thin classes over the ``raw_`` integer functions of
:mod:`hevr.crypto.paillier` for encryption and CRT decryption. Key files (hevr's JSON or
python-paillier's) are built and written by :mod:`hevr.crypto.key_json` (the classes' ``to_dict`` and
``save`` hand over to it) and read by :mod:`hevr.crypto.keyfile` and :mod:`hevr.crypto.phe_keys`.

>>> import warnings, hevr
>>> with warnings.catch_warnings():
...     warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
...     pub, priv = hevr.generate_keypair(bits=256)
>>> priv.decrypt(pub.add(pub.encrypt(20), priv.encrypt(22)))
42

Secret material (p, q and everything derived from them) never appears in a ``repr``, a
log line or an exception message; private key files are created with mode 0600.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Callable, Iterable, Sequence
from numbers import Integral
from typing import Any

import gmpy2
import numpy as np
from gmpy2 import mpz

from ..errors import InsecureKeyWarning, KeyMismatchError, ParameterError
from . import paillier as raw
from .encoding import decode
from .key_json import KEY_FORMATS, private_dict, public_dict, write_key
from .number import EncryptedNumber
from .owner import OwnerEncryptor, owner_tables
from .paillier import factor_problem
from .primes import random_prime_with_factors
from .public_masks import public_mask
from .records import record_width

log = logging.getLogger(__name__)

MIN_BITS, MAX_BITS, SECURE_BITS = 64, 4096, 2048


__all__ = [
    "PublicKey",
    "PrivateKey",
    "generate_keypair",
    "factor_problem",
    "KEY_FORMATS",
    "MIN_BITS",
    "MAX_BITS",
    "SECURE_BITS",
]


def _as_int_list(values: np.ndarray | Iterable[int], name: str) -> list[int]:
    if isinstance(values, np.ndarray):
        if values.dtype.kind not in "iub" and values.dtype != object:
            raise ParameterError(f"{name} must hold integers; got dtype {values.dtype}")
        return [int(v) for v in values.ravel().tolist()]
    return [int(v) for v in values]


class PublicKey:
    """Paillier public key (n, g = n + 1).

    Parameters
    ----------
    n : int
        The modulus, a product of two distinct primes.

    Examples
    --------
    >>> pub = PublicKey(11 * 13)
    >>> pub.bits
    8
    """

    __slots__ = ("n", "nsquare", "g", "bits", "max_int", "_fingerprint")

    def __init__(self, n: int) -> None:
        if isinstance(n, bool) or not isinstance(n, (Integral, type(mpz(0)))) or n < 15:
            raise ParameterError(f"n must be an integer >= 15; got {type(n).__name__}")
        self.n = mpz(n)
        self.nsquare = self.n * self.n
        self.g = self.n + 1
        self.bits = int(self.n.bit_length())
        self.max_int = raw.max_int(self.n)
        self._fingerprint: str | None = None

    # -- identity -----------------------------------------------------------------
    @property
    def fingerprint(self) -> str:
        """Hex SHA-256 of n as big-endian bytes."""
        if self._fingerprint is None:
            self._fingerprint = raw.fingerprint(self.n)
        return self._fingerprint

    @property
    def ciphertext_bytes(self) -> int:
        """Fixed byte width of a ciphertext (n² < 2^(2·bits))."""
        return record_width(self.n)

    def __repr__(self) -> str:
        return f"PublicKey(bits={self.bits}, fingerprint={self.fingerprint[:16]}…)"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PublicKey) and self.n == other.n

    def __hash__(self) -> int:
        return hash(("hevr.PublicKey", int(self.n)))

    def __reduce__(self) -> tuple[type[PublicKey], tuple[int]]:
        return (PublicKey, (int(self.n),))

    # -- encryption -----------------------------------------------------------------
    def _random_mask(self) -> mpz:
        """h^s mod n²: a fixed base and a short random exponent (:mod:`hevr.crypto.public_masks`)."""
        return public_mask(self.n, self.nsquare)

    def encrypt(self, m: int, *, unsafe_no_obfuscation: bool = False) -> mpz:
        """Encrypt a signed integer ``|m| < n // 3``: ``c = (1 + m·n)·h^s mod n²``.

        The mask h^s (h = x^n a fixed random n-th residue, s a fresh ⌈bits(n)/2⌉-bit exponent
        from :mod:`secrets`) replaces the textbook r^n: Damgård–Jurik–Nielsen's fixed-base,
        short-exponent variant, ~15× faster at 2048 bits; its security assumption is stated in
        :mod:`hevr.crypto.public_masks`. ``unsafe_no_obfuscation=True`` skips the random mask. The result is NOT
        secure — it exists only to reproduce the paper's "without obfuscation" rows.
        """
        c = raw.raw_encrypt_nude(raw.raw_encode_signed(m, self.n), self.n, self.nsquare)
        if unsafe_no_obfuscation:
            return c
        return raw.raw_obfuscate(c, self._random_mask(), self.nsquare)

    def encrypt_array(self, values: np.ndarray | Sequence[int], *, unsafe_no_obfuscation: bool = False) -> list[mpz]:
        """Encrypt every integer of ``values`` (flattened, C order); returns a list of mpz."""
        return [self.encrypt(v, unsafe_no_obfuscation=unsafe_no_obfuscation) for v in _as_int_list(values, "values")]

    def encrypt_number(self, value: float, exponent: int | None = None) -> EncryptedNumber:
        """Encrypt a plain number as an :class:`EncryptedNumber` (see :func:`hevr.crypto.encoding.encode`)."""
        return EncryptedNumber.encrypt(self, value, exponent, self.encrypt)

    # -- homomorphic operations ------------------------------------------------------
    def add(self, c1: int, c2: int) -> mpz:
        """⊕: a ciphertext of m1 + m2."""
        return raw.raw_add(mpz(c1), mpz(c2), self.nsquare)

    def sub(self, c1: int, c2: int) -> mpz:
        """A ciphertext of m1 - m2."""
        return raw.raw_sub(mpz(c1), mpz(c2), self.nsquare)

    def neg(self, c: int) -> mpz:
        """A ciphertext of -m."""
        return raw.raw_neg(mpz(c), self.nsquare)

    def mul(self, c: int, k: int) -> mpz:
        """⊗: a ciphertext of m·k for a plain integer k (negative allowed)."""
        if isinstance(k, bool) or not isinstance(k, (Integral, type(mpz(0)))):
            raise ParameterError(f"k must be an int; got {type(k).__name__} (use EncryptedNumber for floats)")
        return raw.raw_mul(mpz(c), k, self.n, self.nsquare)

    def check_ciphertext(self, c: int) -> None:
        """Raise ParameterError unless 0 < c < n² and gcd(c, n) = 1."""
        c = mpz(c)
        if not 0 < c < self.nsquare:
            raise ParameterError("ciphertext must lie in (0, n²); got a value outside that range")
        if gmpy2.gcd(c, self.n) != 1:
            raise ParameterError("ciphertext must be coprime to n; got one that is not")

    # -- files (:mod:`hevr.crypto.key_json`) -----------------------------------------------
    def to_dict(self, format: str = "hevr") -> dict[str, Any]:
        """The JSON object of the key file: ``format="hevr"`` (hevr's) or ``"phe"`` (pheutil's)."""
        return public_dict(self.n, format)

    def save(self, path: str | os.PathLike[str], overwrite: bool = False, format: str = "hevr") -> None:
        """Write the public key as JSON (world-readable is fine); read it with :func:`hevr.load_key`.
        An existing file is replaced only with ``overwrite=True`` (:class:`hevr.ExistingFileError`).
        ``format="phe"`` writes python-paillier's ``pheutil`` JSON instead of hevr's
        (:func:`hevr.crypto.key_json.write_key`)."""
        write_key(path, self.to_dict(format), secret=False, overwrite=overwrite)


class PrivateKey:
    """Paillier private key (p, q) with precomputed CRT constants, and the key holder's policy.

    Encryption with a private key (:meth:`encrypt`) uses the owner-side fast path of
    :mod:`hevr.crypto.owner`: the same ciphertext distribution as :meth:`PublicKey.encrypt`,
    many times faster.

    ``require_tags``, the key's policy (kept in its file; on for :func:`generate_keypair`'s keys,
    :meth:`with_policy` or ``hevr key-policy`` for others): every store of this key carries tags, so
    the owner's encryption writes them unasked, and a store without them is refused before a render
    where the key is known and at decryption (:mod:`hevr.image.provenance`), unless accepted
    explicitly (``hevr.trust_store(ev, key, untagged=True)``).
    """

    __slots__ = ("public_key", "p", "q", "_psquare", "_qsquare", "_hp", "_hq", "_p_inv_q", "_owner", "require_tags")

    def __init__(self, public_key: PublicKey, p: int, q: int, *, require_tags: bool = False) -> None:
        if not isinstance(require_tags, bool):
            raise ParameterError(f"require_tags: expected True or False, got {require_tags!r:.40}")
        self.require_tags = require_tags
        p, q = mpz(p), mpz(q)
        if p > q:
            p, q = q, p
        if p * q != public_key.n:
            raise ParameterError("p·q does not equal the public modulus n")
        self.public_key = public_key
        self.p, self.q = p, q
        self._psquare, self._qsquare = p * p, q * q
        self._hp = raw.raw_crt_h(p, self._psquare, public_key.g)
        self._hq = raw.raw_crt_h(q, self._qsquare, public_key.g)
        self._p_inv_q = mpz(gmpy2.invert(p, q))
        self._owner: OwnerEncryptor | None = None

    def __repr__(self) -> str:
        return f"PrivateKey(bits={self.public_key.bits}, fingerprint={self.public_key.fingerprint[:16]}…)"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PrivateKey) and self.public_key == other.public_key

    def __hash__(self) -> int:
        return hash(("hevr.PrivateKey", int(self.public_key.n)))

    def __reduce__(self) -> tuple[Callable[[PublicKey, int, int, bool], PrivateKey], tuple[PublicKey, int, int, bool]]:
        # Tables are rebuilt where they are needed rather than shipped.
        return (_private_key, (self.public_key, int(self.p), int(self.q), self.require_tags))

    def with_policy(self, *, require_tags: bool) -> PrivateKey:
        """The same key with the policy ``require_tags`` (class docstring; ``save(path, overwrite=True)`` keeps it).

        >>> import warnings
        >>> with warnings.catch_warnings():
        ...     warnings.simplefilter("ignore")
        ...     pub, priv = generate_keypair(64, require_tags=False)
        >>> strict = priv.with_policy(require_tags=True)
        >>> priv.require_tags, strict.require_tags, strict == priv
        (False, True, True)
        """
        return PrivateKey(self.public_key, int(self.p), int(self.q), require_tags=require_tags)

    @property
    def fingerprint(self) -> str:
        return self.public_key.fingerprint

    # -- encryption (owner-side fast path) ------------------------------------------
    @property
    def owner(self) -> OwnerEncryptor:
        if self._owner is None:
            self._owner = owner_tables(self.p, self.q)
        return self._owner

    def encrypt(self, m: int, *, unsafe_no_obfuscation: bool = False) -> mpz:
        """Encrypt a signed integer with the owner-side fast path (same distribution)."""
        pub = self.public_key
        residue = raw.raw_encode_signed(m, pub.n)
        if unsafe_no_obfuscation:
            return raw.raw_encrypt_nude(residue, pub.n, pub.nsquare)
        return self.owner.encrypt_residues((residue,))[0]

    def encrypt_array(self, values: np.ndarray | Sequence[int], *, unsafe_no_obfuscation: bool = False) -> list[mpz]:
        """Encrypt every integer of ``values`` (flattened, C order) on the fast path."""
        pub = self.public_key
        n = pub.n
        residues = [raw.raw_encode_signed(v, n) for v in _as_int_list(values, "values")]
        if unsafe_no_obfuscation:
            return [raw.raw_encrypt_nude(m, n, pub.nsquare) for m in residues]
        return self.owner.encrypt_residues(residues)

    def encrypt_number(self, value: float, exponent: int | None = None) -> EncryptedNumber:
        return EncryptedNumber.encrypt(self.public_key, value, exponent, self.encrypt)

    # -- decryption ----------------------------------------------------------------
    def raw_decrypt(self, c: int) -> mpz:
        """Residue m in [0, n) (no signed decoding)."""
        c = mpz(c)
        if not 0 < c < self.public_key.nsquare:
            raise ParameterError("ciphertext must lie in (0, n²); got a value outside that range")
        return raw.raw_decrypt_crt(c, self.p, self.q, self._psquare, self._qsquare, self._hp, self._hq, self._p_inv_q)

    def decrypt(self, c: int) -> int:
        """Signed plaintext; :class:`hevr.PlaintextOverflowError` in the ambiguous band."""
        return int(raw.raw_decode_signed(self.raw_decrypt(c), self.public_key.n))

    def crt_constants(self) -> tuple[mpz, mpz, mpz, mpz, mpz]:
        """``(p, q, h_p, h_q, p^-1 mod q)`` of CRT decryption (secret: for a decryption kernel in this
        process, never stored or logged)."""
        return self.p, self.q, self._hp, self._hq, self._p_inv_q

    def decrypt_array(self, ciphertexts: Iterable[int], signed: bool = True) -> list[int]:
        """Decrypt many ciphertexts (CRT each, the exponentiations batched over the CPUs' threads:
        :func:`hevr.crypto.paillier.raw_decrypt_crt_list`); returns Python ints."""
        n = self.public_key.n
        n2 = self.public_key.nsquare
        p, q, p2, q2 = self.p, self.q, self._psquare, self._qsquare
        hp, hq, piq = self._hp, self._hq, self._p_inv_q
        cs = []
        for c in ciphertexts:  # every ciphertext checked before any is decrypted
            c = mpz(c)
            if not 0 < c < n2:
                raise ParameterError("ciphertext must lie in (0, n²); got a value outside that range")
            cs.append(c)
        ms = raw.raw_decrypt_crt_list(cs, p, q, p2, q2, hp, hq, piq)  # batched, on the CPUs' threads
        return [int(raw.raw_decode_signed(m, n)) if signed else int(m) for m in ms]

    def decrypt_number(self, x: EncryptedNumber) -> float:
        """Decrypt an :class:`EncryptedNumber` to the nearest float."""
        return decode(self.decrypt_number_mantissa(x), x.exponent)

    def decrypt_number_mantissa(self, x: EncryptedNumber) -> int:
        if x.public_key != self.public_key:
            raise KeyMismatchError(
                f"number was encrypted under key {x.public_key.fingerprint[:16]}…, "
                f"this private key is {self.fingerprint[:16]}…"
            )
        return self.decrypt(x.ciphertext)

    # -- files (:mod:`hevr.crypto.key_json`) -----------------------------------------------
    def to_dict(self, format: str = "hevr") -> dict[str, Any]:
        """The JSON object of the key file (secret): ``format="hevr"`` or ``"phe"`` (pheutil's)."""
        return private_dict(self.p, self.q, self.require_tags, format)

    def save(self, path: str | os.PathLike[str], overwrite: bool = False, format: str = "hevr") -> None:
        """Write the private key as JSON, created with mode 0600 (atomically); read it with
        :func:`hevr.load_key`. An existing file is never replaced unless ``overwrite=True``
        (:class:`hevr.ExistingFileError`): a key written over loses every image it decrypts.
        ``format="phe"`` writes python-paillier's ``pheutil`` JSON instead of hevr's
        (:func:`hevr.crypto.key_json.write_key`)."""
        write_key(path, self.to_dict(format), secret=True, overwrite=overwrite)


def _private_key(public_key: PublicKey, p: int, q: int, require_tags: bool) -> PrivateKey:
    """Unpickling (:meth:`PrivateKey.__reduce__`): the policy is keyword-only."""
    return PrivateKey(public_key, p, q, require_tags=require_tags)


def generate_keypair(bits: int = 2048, *, require_tags: bool = True) -> tuple[PublicKey, PrivateKey]:
    """Generate a Paillier key pair (supplementary Alg. "Create Keys").

    ``require_tags`` (default True): the private key's policy that every store of this key
    carries tags (:class:`PrivateKey`); False makes a key without it.

    p ≠ q are random primes of bits/2 bits from :mod:`secrets`, n has exactly ``bits``
    bits, g = n + 1 and gcd(n, (p-1)(q-1)) = 1. Sizes below 2048 bits emit
    :class:`hevr.InsecureKeyWarning`.

    Examples
    --------
    >>> import warnings
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     pub, priv = generate_keypair(64)
    >>> pub.bits
    64
    """
    if isinstance(bits, bool) or not isinstance(bits, Integral) or bits % 2 or not MIN_BITS <= bits <= MAX_BITS:
        raise ParameterError(f"bits must be an even integer in [{MIN_BITS}, {MAX_BITS}]; got {bits!r}")
    if not isinstance(require_tags, bool):
        raise ParameterError(f"require_tags: expected True or False, got {require_tags!r:.40}")
    bits = int(bits)
    if bits < SECURE_BITS:
        warnings.warn(
            f"a {bits}-bit Paillier key is not secure; use at least {SECURE_BITS} bits",
            InsecureKeyWarning,
            stacklevel=2,
        )
    half = bits // 2
    while True:
        p, _ = random_prime_with_factors(half)
        q, _ = random_prime_with_factors(half)
        if p == q:
            continue
        n = p * q
        if n.bit_length() != bits or gmpy2.gcd(n, (p - 1) * (q - 1)) != 1:
            continue
        pub = PublicKey(n)
        log.info("generated a %d-bit Paillier key %s", bits, pub.fingerprint[:16])
        return pub, PrivateKey(pub, p, q, require_tags=require_tags)
