"""JSON key files: validated loading (writing is :meth:`PublicKey.save` / :meth:`PrivateKey.save`,
private files 0600, atomically).

A key file is a JSON object ``{"format": "hevr-key", "version": 1, "kind":
"public"|"private", "bits": …, "n": "…", "fingerprint": "…"}`` plus ``"p"`` and ``"q"``
(decimal strings) for private keys. Loading checks everything that can be checked —
format, sizes, p·q = n, primality, fingerprint — and reports problems without ever
quoting a secret value.

:func:`load_key` also reads the key files of python-paillier's ``pheutil`` (a JSON object
with ``"kty": "DAJ"``; see :mod:`hevr.crypto.phe_keys`), with the same limits and checks.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

from gmpy2 import mpz

from .._files import require_file
from .._validate import is_decimal
from ..errors import InsecureKeyWarning, InvalidKeyError
from .keys import MAX_BITS, MIN_BITS, SECURE_BITS, PrivateKey, PublicKey, factor_problem
from .phe_keys import is_phe_dict, key_from_phe_dict

__all__ = ["MAX_KEY_FILE_BYTES", "load_key"]

# A private key file of MAX_BITS holds about 2.5 kB: anything much bigger is not a key file,
# and is refused before it is read into memory.
MAX_KEY_FILE_BYTES = 1 << 16
# Decimal digits of the largest n a key file may hold (MAX_BITS bits); p and q have fewer.
_MAX_DIGITS = math.ceil(MAX_BITS * math.log10(2)) + 1


def _int_field(d: dict, name: str, path: Path) -> mpz:
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
    raise InvalidKeyError(f"key file {path}: field {name!r}: expected a decimal string of at most "
                          f"{_MAX_DIGITS} ASCII digits 0-9, got {got}")


def _read_text(path: Path) -> str:
    """The file's text: UTF-8, at most MAX_KEY_FILE_BYTES bytes."""
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise InvalidKeyError(f"key file {path} cannot be read: {exc.strerror}") from None
    if len(data) > MAX_KEY_FILE_BYTES:
        raise InvalidKeyError(f"key file {path}: expected at most {MAX_KEY_FILE_BYTES} bytes, got a "
                              "larger file (not a key file?)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidKeyError(f"key file {path}: expected UTF-8 JSON text, got a byte that is not UTF-8 "
                              f"at offset {exc.start}") from None


def _parse(text: str, path: Path) -> object:
    """The file's JSON value."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidKeyError(f"key file {path} is not valid JSON (line {exc.lineno})") from None
    except ValueError:  # a JSON number of more than 4300 digits (Python's int limit)
        raise InvalidKeyError(f"key file {path} is not a key file: its JSON holds a number too long to "
                              "read") from None
    except RecursionError:  # "[[[[…" deeper than the parser's stack
        raise InvalidKeyError(f"key file {path} is not a key file: its JSON is nested too deeply") from None


def load_key(path) -> PublicKey | PrivateKey:
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
        bits = key.public_key.bits if isinstance(key, PrivateKey) else key.bits
        if bits < SECURE_BITS:
            warnings.warn(f"key file {path} holds a {bits}-bit key, which is not secure", InsecureKeyWarning,
                          stacklevel=2)
        return key
    if not isinstance(d, dict) or d.get("format") != "hevr-key":
        raise InvalidKeyError(f"key file {path}: expected format 'hevr-key' (or a python-paillier key, "
                              "kty 'DAJ')")
    if type(d.get("version")) is not int or d.get("version") != 1:
        raise InvalidKeyError(f"key file {path}: unsupported version {d.get('version')!r}, expected 1")
    kind = d.get("kind")
    if kind not in ("public", "private"):
        raise InvalidKeyError(f"key file {path}: kind must be 'public' or 'private'; got {kind!r}")
    n = _int_field(d, "n", path)
    bits = int(n.bit_length())
    if bits % 2 or not MIN_BITS <= bits <= MAX_BITS:
        raise InvalidKeyError(f"key file {path}: n must have an even number of bits in [{MIN_BITS}, {MAX_BITS}]; got {bits}")
    if d.get("bits") is not None and (type(d.get("bits")) is not int or d.get("bits") != bits):
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
    problem = factor_problem(n, p, q)
    if problem is not None:
        raise InvalidKeyError(f"key file {path}: {problem}")
    return PrivateKey(pub, p, q)
