"""The JSON objects of key files, built from a key's integers, and writing one: hevr's format
(:mod:`hevr.crypto.keyfile` describes and reads it) or the JSON of python-paillier's ``pheutil``
(:mod:`hevr.crypto.phe_keys`), integers there as unpadded base64url of their big-endian bytes.
A private key's file is created with mode 0600, atomically, never over an existing file unless
asked (:func:`write_key`). The key classes' ``to_dict`` and ``save`` call these; this module
knows no key class.

>>> sorted(public_dict(65537 * 65539))
['bits', 'fingerprint', 'format', 'kind', 'n', 'version']
>>> public_dict(65537 * 65539, "phe")["n"]
'AQAEAAM'
"""

from __future__ import annotations

import base64
import json
import os
from typing import Any

from ..core.files import write_atomic
from ..errors import ParameterError
from .paillier import fingerprint

__all__ = ["KEY_FORMATS", "b64url", "check_format", "private_dict", "public_dict", "write_key"]

# Key-file formats a key is saved in: hevr's own, and the JSON of python-paillier's ``pheutil``.
KEY_FORMATS = ("hevr", "phe")


def check_format(format: str) -> str:
    """``format`` if it is one of :data:`KEY_FORMATS`, else :class:`hevr.ParameterError`.

    >>> check_format("pem")
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: format: expected 'hevr' or 'phe', got 'pem'
    """
    if not isinstance(format, str) or format not in KEY_FORMATS:
        raise ParameterError(f"format: expected 'hevr' or 'phe', got {format!r:.40}")
    return format


def b64url(x: int) -> str:
    """A positive integer as unpadded base64url of its minimal big-endian bytes (JWK style,
    as python-paillier's ``phe.util.int_to_base64``).

    >>> b64url(65537)
    'AQAB'
    """
    x = int(x)
    return base64.urlsafe_b64encode(x.to_bytes((x.bit_length() + 7) // 8, "big")).rstrip(b"=").decode("ascii")


def public_dict(n: int, format: str = "hevr") -> dict[str, Any]:
    """The JSON object of the public key of modulus ``n``: ``format="hevr"`` or ``"phe"``."""
    n = int(n)
    if check_format(format) == "phe":
        return {
            "kty": "DAJ",
            "alg": "PAI-GN1",
            "key_ops": ["encrypt"],
            "n": b64url(n),
            "kid": f"Paillier public key exported by hevr, fingerprint {fingerprint(n)}",
        }
    return {
        "format": "hevr-key",
        "version": 1,
        "kind": "public",
        "bits": n.bit_length(),
        "n": str(n),
        "fingerprint": fingerprint(n),
    }


def private_dict(p: int, q: int, require_tags: bool, format: str = "hevr") -> dict[str, Any]:
    """The JSON object of the private key of primes ``p``, ``q`` and its policy (secret)."""
    p, q = int(p), int(q)
    pub = public_dict(p * q, format)
    if format == "phe":  # checked by the line above
        return {
            "kty": "DAJ",
            "key_ops": ["decrypt"],
            "p": b64url(p),
            "q": b64url(q),
            "pub": pub,
            "kid": f"Paillier private key exported by hevr, fingerprint {fingerprint(p * q)}",
        }
    pub.update(kind="private", p=str(p), q=str(q), policy={"require_tags": require_tags})
    return pub


def write_key(path: str | os.PathLike[str], d: dict[str, Any], *, secret: bool, overwrite: bool = False) -> None:
    """Write the key file ``d`` as JSON, atomically: mode 0600 when ``secret`` (a private key), else
    0644. An existing file is replaced only with ``overwrite=True`` (:class:`hevr.ExistingFileError`)."""
    text = json.dumps(d, indent=1) + "\n"
    write_atomic(path, text, mode=0o600 if secret else 0o644, overwrite=overwrite)
