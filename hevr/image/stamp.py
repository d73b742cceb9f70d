"""The key holder's stamp on a verified ``.hevr`` file (issue 38): "I checked this frame".

A frame's verification record (:class:`hevr.rendering.verification.Verification`) is a proof only if the
seed of its coefficients was drawn by the key holder *after* the image was fixed: a server that
drew (or learnt) the seed first can fit a wrong image to it, and anyone who can write the file can
put a genuine record beside other pixels. So a file is trusted as verified only when it carries the
key holder's own MAC over its bytes, made when the key holder's process had just checked it:

    K_stamp = HMAC-SHA256(k, "hevr-frame-stamp-v1")               (k: the tag key's PRF key)
    stamp   = HMAC-SHA256(K_stamp, SHA-256(canonical header without "stamp") ‖ SHA-256(body))

The header's ``saved_as`` (where the key holder saved it: a local file's absolute real path, a
URL without its query) and ``rendered_at`` (when its seed was drawn, UTC) are under the stamp too.
A stamped frame read from another place proves what it shows (its store and view:
:mod:`hevr.image.proof`), not that it belongs where it was found — a genuine verified frame of
another patient, view or render copied over this one: :mod:`hevr.image.provenance` says so, and
``require_verified`` refuses it unless the caller states what it expects. And a frame of a store
that the owner has since replaced (the key holder's known stores, :mod:`hevr.store.known`) is
refused: an old frame replayed.

(the header's canonical form: :func:`hevr.crypto.mac.canonical`; the
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
import os
import re
import time
from pathlib import Path
from typing import Any, NamedTuple
from urllib.parse import urlsplit, urlunsplit

from ..crypto.mac import PREFIX, check_tag, derive_key, digest, raw_mac
from ..crypto.tags import tag_key_of

__all__ = [
    "STAMP_FIELDS",
    "STAMP_PREFIX",
    "Stamp",
    "check_stamp",
    "read_stamp",
    "rendered_at",
    "utc",
    "make_stamp",
    "message",
    "raw_check",
    "raw_stamp",
    "saved_name",
    "stamp_header",
]

STAMP_PREFIX = PREFIX
_STAMP = re.compile(r"hmac-sha256:[0-9a-f]{64}")
TIME_FORMAT = "%Y-%m-%dT%H:%M:%SZ"


class Stamp(NamedTuple):
    """A file's key holder stamp as read: the stamp, what it authenticates (:func:`message`), where
    the key holder saved the file, when the frame was rendered (UTC, ``""`` for files of before issue
    47) and where it was read from (None: bytes not read from a named file)."""

    stamp: str
    message: bytes
    saved_as: str
    rendered_at: str = ""
    read_as: str | None = None


def utc(seconds: float) -> str:
    """``seconds`` since the epoch as the stamp's UTC time.

    >>> utc(0)
    '1970-01-01T00:00:00Z'
    """
    return time.strftime(TIME_FORMAT, time.gmtime(seconds))


def rendered_field(value: Any) -> str:
    """A header's ``rendered_at`` if it is a stamp time, else ``""`` (a file's field is checked by its reader).

    >>> rendered_field("2026-11-28T18:00:00Z"), rendered_field(3)
    ('2026-11-28T18:00:00Z', '')
    """
    if isinstance(value, str) and len(value) == 20:
        try:
            time.strptime(value, TIME_FORMAT)
            return value
        except ValueError:
            return ""
    return ""


def message(header: dict, body_digest: bytes) -> bytes:
    """What a stamp authenticates: SHA-256 of the canonical header (its ``stamp`` left out) and the
    body's SHA-256."""
    head = {k: v for k, v in header.items() if k != "stamp"}
    return digest(head) + bytes(body_digest)


def saved_name(path: str | Path) -> str:
    """The place a stamp binds (:mod:`hevr.image.stamp`): a local file's absolute real path
    (symbolic links resolved), a URL as scheme, host and path — without user, password, query or
    fragment, which never go into a file.

    >>> saved_name("https://user:pw@Host.org:8/x/f.hevr?sig=1#a"), saved_name("S3://b/x.hevr")
    ('https://host.org:8/x/f.hevr', 's3://b/x.hevr')
    >>> saved_name("file://localhost/b/f.hevr") == saved_name("file:///b/f.hevr") == saved_name("/b/f.hevr")
    True
    """
    text = str(path)
    if "://" in text:
        u = urlsplit(text)
        if u.scheme.lower() != "file":
            host = (u.hostname or "") + (f":{u.port}" if u.port else "")
            return urlunsplit((u.scheme.lower(), host, u.path, "", ""))
        text = u.path
    return os.path.realpath(os.path.expanduser(text))


def raw_stamp(prf_key: bytes, msg: bytes) -> str:
    """The stamp of ``msg`` under the tag key's PRF key ``prf_key``."""
    return raw_mac(derive_key(prf_key, b"hevr-frame-stamp-v1"), msg)


def raw_check(prf_key: bytes, msg: bytes, stamp: Any) -> bool:
    """Whether ``stamp`` is the stamp of ``msg`` (constant-time comparison)."""
    return isinstance(stamp, str) and _STAMP.fullmatch(stamp) is not None and check_tag(raw_stamp(prf_key, msg), stamp)


def make_stamp(private_key: Any, msg: bytes) -> str:
    """The key holder's stamp of ``msg`` (:func:`message`)."""
    return raw_stamp(tag_key_of(private_key).prf_key, msg)


def check_stamp(private_key: Any, msg: bytes, stamp: Any) -> bool:
    """Whether ``stamp`` is the key holder's stamp of ``msg``."""
    return raw_check(tag_key_of(private_key).prf_key, msg, stamp)


STAMP_FIELDS = ("stamp", "saved_as", "rendered_at")  # a stamped file's header fields beside its record


def read_stamp(h: dict, body_digest: bytes, fail: Any) -> Stamp | None:
    """A file header's stamp (None: not stamped), checked before any field is rewritten; a bad
    field is ``fail(name, expected, got)`` (which raises: the reader's own error). The one reader of
    every frame file's stamp (per-voxel and packed)."""
    if not any(k in h for k in STAMP_FIELDS):
        return None
    s = h.get("stamp")
    if not (isinstance(s, str) and _STAMP.fullmatch(s) and "verification" in h):
        raise fail("stamp", f"'{STAMP_PREFIX}<64 hex>' beside a verification record", s)
    if not (isinstance(h.get("saved_as"), str) and len(h["saved_as"]) <= 4096):
        raise fail(
            "saved_as", "where the key holder saved the frame (a string of at most 4096 characters)", h.get("saved_as")
        )
    when = h.get("rendered_at", "")
    if when != "" and not rendered_field(when):
        raise fail("rendered_at", "a UTC time YYYY-MM-DDTHH:MM:SSZ", when)
    return Stamp(s, message(h, body_digest), h["saved_as"], when)


def rendered_at(img: Any) -> str:
    """When a frame with a verification record was rendered: its stamp's time (a frame read from a
    file keeps it when stamped again), else when its seed was drawn in this process."""
    stamp = getattr(img, "stamp", None)  # a slice is never read from a file
    if stamp is not None:
        return stamp.rendered_at
    drawn = getattr(img.verification, "drawn_at", 0.0)
    return utc(drawn) if drawn else ""


def stamp_header(header: dict, body: list, img: Any, private_key: Any, saved_as: str) -> None:
    """Add ``saved_as``, ``rendered_at`` and ``stamp`` to the ``header`` of a verified frame file whose
    record body parts are ``body``: a fresh stamp with ``private_key`` (whose holder checked the
    frame), else the stamp the frame was read with; nothing for a frame without a verification
    record. The one rule of every frame file (per-voxel and packed)."""
    if img.verification is None:
        return
    if private_key is not None:
        digest = hashlib.sha256()
        for part in body:
            digest.update(part)
        header["saved_as"] = str(saved_as)
        when = rendered_at(img)
        if when:
            header["rendered_at"] = when
        header["stamp"] = make_stamp(private_key, message(header, digest.digest()))
    elif img.stamp is not None:
        header["saved_as"], header["stamp"] = img.stamp.saved_as, img.stamp.stamp
        if img.stamp.rendered_at:
            header["rendered_at"] = img.stamp.rendered_at
