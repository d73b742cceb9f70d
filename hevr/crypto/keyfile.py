"""JSON key files: validated loading (writing is :meth:`PublicKey.save` / :meth:`PrivateKey.save`,
private files 0600, atomically).

A key file is a JSON object ``{"format": "hevr-key", "version": 1, "kind":
"public"|"private", "bits": …, "n": "…", "fingerprint": "…"}`` plus ``"p"`` and ``"q"``
(decimal strings) for private keys. Loading checks everything that can be checked —
format, sizes, p·q = n, primality, fingerprint — and reports problems without ever
quoting a secret value.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import gmpy2
from gmpy2 import mpz

from .._files import require_file
from ..errors import InsecureKeyWarning, InvalidKeyError
from .keys import MAX_BITS, MIN_BITS, SECURE_BITS, PrivateKey, PublicKey
from .primes import is_probable_prime

__all__ = ["load_key"]


def _int_field(d: dict, name: str, path: Path) -> mpz:
    v = d.get(name)
    if not isinstance(v, str) or not v.isdigit():
        raise InvalidKeyError(f"key file {path}: field {name!r} must be a decimal string of digits")
    return mpz(v)


def load_key(path) -> PublicKey | PrivateKey:
    """Load a key file written by :meth:`PublicKey.save` / :meth:`PrivateKey.save`.

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
    try:
        text = path.read_text()
    except OSError as exc:
        raise InvalidKeyError(f"key file {path} cannot be read: {exc.strerror}") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidKeyError(f"key file {path} is not valid JSON (line {exc.lineno})") from None
    if not isinstance(d, dict) or d.get("format") != "hevr-key":
        raise InvalidKeyError(f"key file {path}: expected format 'hevr-key'")
    if d.get("version") != 1:
        raise InvalidKeyError(f"key file {path}: unsupported version {d.get('version')!r}, expected 1")
    kind = d.get("kind")
    if kind not in ("public", "private"):
        raise InvalidKeyError(f"key file {path}: kind must be 'public' or 'private'; got {kind!r}")
    n = _int_field(d, "n", path)
    bits = int(n.bit_length())
    if bits % 2 or not MIN_BITS <= bits <= MAX_BITS:
        raise InvalidKeyError(f"key file {path}: n must have an even number of bits in [{MIN_BITS}, {MAX_BITS}]; got {bits}")
    if d.get("bits") is not None and d.get("bits") != bits:
        raise InvalidKeyError(f"key file {path}: 'bits' says {d.get('bits')} but n has {bits} bits")
    pub = PublicKey(n)
    fp = d.get("fingerprint")
    if fp is not None and fp != pub.fingerprint:
        raise InvalidKeyError(f"key file {path}: fingerprint does not match n (file tampered with?)")
    if bits < SECURE_BITS:
        warnings.warn(f"key file {path} holds a {bits}-bit key, which is not secure", InsecureKeyWarning, stacklevel=2)
    if kind == "public":
        return pub
    p, q = _int_field(d, "p", path), _int_field(d, "q", path)
    if p * q != n:
        raise InvalidKeyError(f"key file {path}: p·q does not equal n (file tampered with?)")
    if p == q:
        raise InvalidKeyError(f"key file {path}: p and q must be distinct")
    if p.bit_length() != bits // 2 or q.bit_length() != bits // 2:
        raise InvalidKeyError(f"key file {path}: p and q must each have {bits // 2} bits")
    if not (is_probable_prime(p) and is_probable_prime(q)):
        raise InvalidKeyError(f"key file {path}: p or q is not prime")
    if gmpy2.gcd(n, (p - 1) * (q - 1)) != 1:
        raise InvalidKeyError(f"key file {path}: gcd(n, (p-1)(q-1)) must be 1")
    return PrivateKey(pub, p, q)
