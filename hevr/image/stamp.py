"""The key holder's stamp on a verified ``.hevr`` file (issue 38): "I checked this frame".

A frame's verification record (:class:`hevr.rendering.verify.Verification`) is a proof only if the
seed of its coefficients was drawn by the key holder *after* the image was fixed: a server that
drew (or learnt) the seed first can fit a wrong image to it, and anyone who can write the file can
put a genuine record beside other pixels. So a file is trusted as verified only when it carries the
key holder's own MAC over its bytes, made when the key holder's process had just checked it:

    K_stamp = HMAC-SHA256(k, "hevr-frame-stamp-v1")               (k: the tag key's PRF key)
    stamp   = HMAC-SHA256(K_stamp, SHA-256(canonical header without "stamp") ‖ SHA-256(body))

The header's ``saved_as`` (the file name the key holder saved it as) is under the stamp too, and a
stamped frame read under another name is refused: a genuine verified frame of another view, level
or store put in this one's place. And a frame of a store that the owner has since replaced (the
key holder's known stores, :mod:`hevr.store.known`) is refused: an old frame replayed.

(the header's canonical form: ``json.dumps(header, sort_keys=True, separators=(",", ":"))``; the
body: the ciphertext records and sample counts, without the file's SHA-256 trailer). Only the
holder of the private key can make or check a stamp; :meth:`hevr.EncryptedImage.decrypt` refuses a
record without a valid stamp (:class:`hevr.VerificationError`), and checks the record again.

>>> m = message({"a": 1, "stamp": "x"}, b"body-digest".ljust(32, b"."))
>>> m == message({"a": 1}, b"body-digest".ljust(32, b".")), len(m)
(True, 64)
>>> s = raw_stamp(bytes(32), m)
>>> raw_check(bytes(32), m, s), raw_check(bytes(32), m[:-1] + b"!", s), raw_check(bytes(32), m, "x")
(True, False, False)
"""

from __future__ import annotations

import hashlib
import hmac
import json
import re
from typing import Any

from ..crypto.tags import tag_key_of

__all__ = ["STAMP_PREFIX", "check_stamp", "make_stamp", "message", "raw_check", "raw_stamp", "saved_name",
           "stamp_header"]

STAMP_PREFIX = "hmac-sha256:"
_STAMP = re.compile(r"hmac-sha256:[0-9a-f]{64}")


def message(header: dict, body_digest: bytes) -> bytes:
    """What a stamp authenticates: SHA-256 of the canonical header (its ``stamp`` left out) and the
    body's SHA-256."""
    head = {k: v for k, v in header.items() if k != "stamp"}
    text = json.dumps(head, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()
    return hashlib.sha256(text).digest() + bytes(body_digest)


def saved_name(path: str | Path) -> str:
    """The name a stamp binds (:mod:`hevr.image.stamp`): the file's last path component.

    >>> saved_name("/a/b/f.hevr"), saved_name("s3://bucket/x/g.hevr?v=1")
    ('f.hevr', 'g.hevr')
    """
    return str(path).split("?")[0].rstrip("/").rsplit("/", 1)[-1]


def _key(prf_key: bytes) -> bytes:
    return hmac.new(bytes(prf_key), b"hevr-frame-stamp-v1", hashlib.sha256).digest()


def raw_stamp(prf_key: bytes, msg: bytes) -> str:
    """The stamp of ``msg`` under the tag key's PRF key ``prf_key``."""
    return STAMP_PREFIX + hmac.new(_key(prf_key), msg, hashlib.sha256).hexdigest()


def raw_check(prf_key: bytes, msg: bytes, stamp: Any) -> bool:
    """Whether ``stamp`` is the stamp of ``msg`` (constant-time comparison)."""
    return isinstance(stamp, str) and _STAMP.fullmatch(stamp) is not None and hmac.compare_digest(
        raw_stamp(prf_key, msg), stamp)


def make_stamp(private_key: Any, msg: bytes) -> str:
    """The key holder's stamp of ``msg`` (:func:`message`)."""
    return raw_stamp(tag_key_of(private_key).prf_key, msg)


def check_stamp(private_key: Any, msg: bytes, stamp: Any) -> bool:
    """Whether ``stamp`` is the key holder's stamp of ``msg``."""
    return raw_check(tag_key_of(private_key).prf_key, msg, stamp)


def stamp_header(header: dict, body: list, img: Any, private_key: Any, saved_as: str) -> None:
    """Add ``saved_as`` and ``stamp`` to the ``header`` of a verified frame file whose record body
    parts are ``body``: a fresh stamp with ``private_key`` (whose holder checked the frame), else the
    stamp the frame was read with; nothing for a frame without a verification record. The one rule
    of every frame file (per-voxel and packed)."""
    if img.verification is None:
        return
    if private_key is not None:
        digest = hashlib.sha256()
        for part in body:
            digest.update(part)
        header["saved_as"] = str(saved_as)
        header["stamp"] = make_stamp(private_key, message(header, digest.digest()))
    elif img.stamp is not None:
        header["saved_as"], header["stamp"] = img.stamp[2], img.stamp[0]
