"""JSON key files: validated loading (writing is :meth:`PublicKey.save` / :meth:`PrivateKey.save`,
:mod:`hevr.crypto.key_json`: private files 0600, atomically).

A key file is a JSON object ``{"format": "hevr-key", "version": 1, "kind":
"public"|"private", "bits": …, "n": "…", "fingerprint": "…"}`` plus ``"p"`` and ``"q"``
(decimal strings) and ``"policy": {"require_tags": true|false}`` (:class:`hevr.PrivateKey`: every
store of this key carries tags; a file without it, written before issue 47, has no policy) for
private keys. Loading checks everything that can be checked —
format, sizes, p·q = n, primality, fingerprint — and reports problems without ever
quoting a secret value. What a file claims is checked too: a public key's n must be able to
be a Paillier modulus (:func:`modulus_problem`: odd, not a square, not prime, no factor below
2^16), a file of kind ``"public"`` must not hold private fields (a private key file edited to
say public is refused, not loaded as its public half), and a private key file readable or
writable by others is loaded with a :class:`hevr.KeyFilePermissionWarning` telling
``chmod 600 PATH`` (a warning, not OpenSSH's refusal: pheutil writes its keys 0644, and some
filesystems cannot hold 0600).

:func:`load_key` also reads the key files of python-paillier's ``pheutil`` (a JSON object
with ``"kty": "DAJ"``; see :mod:`hevr.crypto.phe_keys`), with the same limits and checks.
"""

from __future__ import annotations

import functools
import json
import math
import os
import stat
import warnings
from pathlib import Path
from typing import Any

import gmpy2
from gmpy2 import mpz

from ..core.files import require_file
from ..core.validate import is_decimal
from ..errors import InsecureKeyWarning, InvalidKeyError, KeyFilePermissionWarning
from .keys import MAX_BITS, MIN_BITS, SECURE_BITS, PrivateKey, PublicKey
from .paillier import factor_problem
from .phe_keys import is_phe_dict, key_from_phe_dict

__all__ = ["MAX_KEY_FILE_BYTES", "PRIVATE_FIELDS", "load_key", "modulus_problem"]

# A private key file of MAX_BITS holds about 2.5 kB: anything much bigger is not a key file,
# and is refused before it is read into memory.
MAX_KEY_FILE_BYTES = 1 << 16
# Decimal digits of the largest n a key file may hold (MAX_BITS bits); p and q have fewer.
_MAX_DIGITS = math.ceil(MAX_BITS * math.log10(2)) + 1
# Fields only a private key holds (hevr's p, q; python-paillier's lambda, mu).
PRIVATE_FIELDS = ("p", "q", "lambda", "mu")
# No prime factor of a valid n lies below this: p and q have at least MIN_BITS/2 = 32 bits.
_SMALL_PRIMES_BELOW = 1 << 16


@functools.lru_cache(maxsize=1)
def _small_primorial() -> mpz:
    """The product of every prime below 2^16 (94 000 bits; one gcd tests them all)."""
    out, x = mpz(1), mpz(2)
    while x < _SMALL_PRIMES_BELOW:
        out *= x
        x = gmpy2.next_prime(x)
    return out


def modulus_problem(n: int) -> str | None:
    """What rules ``n`` out as a Paillier modulus p·q (two distinct primes of equal size),
    judged from n alone, or None. n is public, so the answer may quote it or its factors.

    >>> modulus_problem(1000003 * 1000033) is None
    True
    >>> modulus_problem(2**64), modulus_problem(1000003**2), modulus_problem(2**61 - 1)
    ('an even number', 'a perfect square (p = q: the primes must be distinct)', 'a prime')
    >>> modulus_problem(3 * (2**63 + 29))
    'a multiple of the small prime 3'
    """
    n = mpz(n)
    if n % 2 == 0:
        return "an even number"
    if gmpy2.is_square(n):
        return "a perfect square (p = q: the primes must be distinct)"
    if gmpy2.gcd(n, _small_primorial()) != 1:
        small = next(int(x) for x in range(3, _SMALL_PRIMES_BELOW, 2) if n % x == 0)
        return f"a multiple of the small prime {small}"
    if gmpy2.is_prime(n):
        return "a prime"
    return None


def _warn_if_exposed(path: Path) -> None:
    """OpenSSH's check of a private key file: group or others may read or write it."""
    if os.name == "nt":  # pragma: no cover - no POSIX modes
        return
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except OSError:  # pragma: no cover - it was just read
        return
    if mode & 0o077:
        warnings.warn(
            f"UNPROTECTED PRIVATE KEY FILE: key file {path} has permissions {mode:04o}, readable or "
            f"writable by others than its owner, who could decrypt every volume and image of this key; "
            f"run: chmod 600 {path}",
            KeyFilePermissionWarning,
            stacklevel=4,
        )


def _int_field(d: dict[str, Any], name: str, path: Path) -> mpz:
    """Field ``name`` of the key file as an mpz; never quotes the value (it may be secret)."""
    v = d.get(name)
    if is_decimal(v, _MAX_DIGITS):
        return mpz(v)
    if v is None:
        got = "nothing"
    elif not isinstance(v, str):
        got = f"a JSON {type(v).__name__}"
    elif not is_decimal(v, len(v)):
        got = f"a {len(v)}-character string with characters other than 0-9"
    else:
        got = f"{len(v)} digits"
    raise InvalidKeyError(
        f"key file {path}: field {name!r}: expected a decimal string of at most "
        f"{_MAX_DIGITS} ASCII digits 0-9, got {got}"
    )


def _read_text(path: Path) -> str:
    """The file's text: UTF-8, at most MAX_KEY_FILE_BYTES bytes."""
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise InvalidKeyError(f"key file {path} cannot be read: {exc.strerror}") from None
    if len(data) > MAX_KEY_FILE_BYTES:
        raise InvalidKeyError(
            f"key file {path}: expected at most {MAX_KEY_FILE_BYTES} bytes, got a larger file (not a key file?)"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidKeyError(
            f"key file {path}: expected UTF-8 JSON text, got a byte that is not UTF-8 at offset {exc.start}"
        ) from None


def _parse(text: str, path: Path) -> object:
    """The file's JSON value."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidKeyError(f"key file {path} is not valid JSON (line {exc.lineno})") from None
    except ValueError:  # a JSON number of more than 4300 digits (Python's int limit)
        raise InvalidKeyError(f"key file {path} is not a key file: its JSON holds a number too long to read") from None
    except RecursionError:  # "[[[[…" deeper than the parser's stack
        raise InvalidKeyError(f"key file {path} is not a key file: its JSON is nested too deeply") from None


def load_key(path: str | os.PathLike[str]) -> PublicKey | PrivateKey:
    """Load a key file written by :meth:`PublicKey.save` / :meth:`PrivateKey.save` (either
    format), or by python-paillier's ``pheutil`` (:mod:`hevr.crypto.phe_keys`).

    Raises :class:`hevr.InvalidKeyError` for a malformed, inconsistent or tampered file.

    Examples
    --------
    >>> import tempfile, os, warnings, hevr
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     pub, priv = hevr.generate_keypair(128)
    ...     d = tempfile.mkdtemp(); priv.save(os.path.join(d, "k.json"))
    ...     hevr.load_key(os.path.join(d, "k.json")) == priv
    True
    """
    path = require_file(path, "key", "a key file")
    if not path.is_file():  # a folder, a FIFO (reading would block), a device
        raise InvalidKeyError(f"key file {path}: expected a regular file, got something else")
    d = _parse(_read_text(path), path)
    if is_phe_dict(d):
        key = key_from_phe_dict(d, path)
        _check_claims(key, path)
        bits = key.public_key.bits if isinstance(key, PrivateKey) else key.bits
        if bits < SECURE_BITS:
            warnings.warn(
                f"key file {path} holds a {bits}-bit key, which is not secure", InsecureKeyWarning, stacklevel=2
            )
        return key
    if not isinstance(d, dict) or d.get("format") != "hevr-key":
        raise InvalidKeyError(f"key file {path}: expected format 'hevr-key' (or a python-paillier key, kty 'DAJ')")
    if type(d.get("version")) is not int or d.get("version") != 1:
        raise InvalidKeyError(f"key file {path}: unsupported version {d.get('version')!r}, expected 1")
    kind = d.get("kind")
    if kind not in ("public", "private"):
        raise InvalidKeyError(f"key file {path}: kind must be 'public' or 'private'; got {kind!r}")
    held = [f for f in PRIVATE_FIELDS if f in d]
    if kind == "public" and held:
        raise InvalidKeyError(
            f"key file {path}: field 'kind': expected 'private' for a file holding the private "
            f"field{'s' if len(held) > 1 else ''} {', '.join(repr(f) for f in held)}, got "
            "'public' (a private key file edited? a public key file holds no p or q)"
        )
    n = _int_field(d, "n", path)
    bits = int(n.bit_length())
    if bits % 2 or not MIN_BITS <= bits <= MAX_BITS:
        raise InvalidKeyError(
            f"key file {path}: n must have an even number of bits in [{MIN_BITS}, {MAX_BITS}]; got {bits}"
        )
    if d.get("bits") is not None and (type(d.get("bits")) is not int or d.get("bits") != bits):
        raise InvalidKeyError(f"key file {path}: 'bits' says {d.get('bits')} but n has {bits} bits")
    pub = PublicKey(n)
    fp = d.get("fingerprint")
    if fp is not None and fp != pub.fingerprint:
        raise InvalidKeyError(f"key file {path}: fingerprint does not match n (file tampered with?)")
    if bits < SECURE_BITS:
        warnings.warn(f"key file {path} holds a {bits}-bit key, which is not secure", InsecureKeyWarning, stacklevel=2)
    if kind == "public":
        _check_claims(pub, path)
        return pub
    p, q = _int_field(d, "p", path), _int_field(d, "q", path)
    problem = factor_problem(n, p, q)
    if problem is not None:
        raise InvalidKeyError(f"key file {path}: {problem}")
    key = PrivateKey(pub, p, q, require_tags=_policy(d, path))
    _check_claims(key, path)
    return key


def _policy(d: dict[str, Any], path: Path) -> bool:
    """The key's ``require_tags`` policy (:class:`hevr.PrivateKey`): the file's ``policy`` object;
    a file without one (written before issue 47) has none."""
    pol = d.get("policy")
    if pol is None:
        return False
    if not (isinstance(pol, dict) and set(pol) == {"require_tags"} and isinstance(pol["require_tags"], bool)):
        raise InvalidKeyError(
            f"key file {path}: field 'policy': expected {{\"require_tags\": true|false}}, got {json.dumps(pol)[:60]}"
        )
    return pol["require_tags"]


def _check_claims(key: PublicKey | PrivateKey, path: Path) -> None:
    """A public key's n must be able to be p·q (a private key's p and q were checked); a
    private key file should be its owner's alone (a warning)."""
    if isinstance(key, PrivateKey):
        _warn_if_exposed(path)
        return
    problem = modulus_problem(key.n)
    if problem is not None:
        raise InvalidKeyError(
            f"key file {path}: field 'n': expected a product of two distinct odd primes of "
            f"{key.bits // 2} bits each, got {problem}"
        )
