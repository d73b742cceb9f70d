"""Canonical JSON, its digest, and the key holder's MACs: the one home of every digest and MAC
hevr takes over a document, and of the one way a MAC key is derived.

Canonical JSON
    ``json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=True)``, UTF-8 (so
    ASCII) bytes: one byte string per document, whatever the order its keys were built in, in every
    process and on every machine. Floats are written by Python's shortest round-trip ``repr``.

Digest
    ``D(doc) = SHA-256(canonical(doc))`` — the identity of a request (a camera's, a slice plane's, a
    render request's cache ``key()``), of a store's bound metadata (``"sha256:" + hex``) and of a
    frame's view (its first 16 hex digits).

Key derivation
    Every MAC key is derived from the tag key's PRF key ``k`` (32 bytes, itself SHAKE-256 of the
    private key's primes: :func:`hevr.crypto.tags.tag_key_of`) by one rule,

    ``K_label = HMAC-SHA256(k, label)``,

    with one label per use, versioned: ``hevr-metadata-mac-v1`` (a store's metadata MAC,
    :mod:`hevr.store.authenticity`), ``hevr-frame-stamp-v1`` (a frame's stamp,
    :mod:`hevr.image.stamp`), ``hevr-known-stores-v2`` (the known-stores file,
    :mod:`hevr.store.known_file`). HMAC is a PRF keyed by ``k``, so the derived keys are
    independent: a MAC under one label says nothing of another.

MAC
    ``HMAC-SHA256(K_label, message)``, written ``"hmac-sha256:" + hex``; over a document, the message
    is its canonical JSON. Checked in constant time (:func:`hmac.compare_digest`).

The known-answer tests (``tests/crypto/test_mac.py``) fix a key, a document and its tag, so a
change to any of these rules (which would orphan every MAC already written) fails there first.
"""

from __future__ import annotations

import hashlib
import hmac
import json
from typing import Any

from ..errors import ParameterError

__all__ = ["LABELS", "PREFIX", "canonical", "check_tag", "derive_key", "digest", "mac", "raw_mac"]

PREFIX = "hmac-sha256:"
LABELS = frozenset({b"hevr-metadata-mac-v1", b"hevr-frame-stamp-v1", b"hevr-known-stores-v2"})


def canonical(doc: Any) -> bytes:
    """The canonical JSON bytes of ``doc`` (sorted keys, no spaces, ASCII).

    >>> canonical({"b": 1, "a": [2.5, None], "s": "é"})
    b'{"a":[2.5,null],"b":1,"s":"\\\\u00e9"}'
    """
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode("ascii")


def digest(doc: Any) -> bytes:
    """SHA-256 of :func:`canonical` ``(doc)``: 32 bytes, equal across processes.

    >>> digest({"b": 1, "a": 2}) == digest({"a": 2, "b": 1}), len(digest([]))
    (True, 32)
    """
    return hashlib.sha256(canonical(doc)).digest()


def derive_key(prf_key: bytes, label: bytes) -> bytes:
    """``HMAC-SHA256(prf_key, label)``: the MAC key of one use (``label`` one of :data:`LABELS`).

    >>> derive_key(bytes(32), b"hevr-frame-stamp-v1") != derive_key(bytes(32), b"hevr-known-stores-v2")
    True
    """
    if label not in LABELS:
        raise ParameterError(f"label: expected one of {sorted(x.decode() for x in LABELS)}, got {label!r}")
    return hmac.new(bytes(prf_key), label, hashlib.sha256).digest()


def raw_mac(key: bytes, msg: bytes) -> str:
    """``"hmac-sha256:" + hex(HMAC-SHA256(key, msg))``.

    >>> raw_mac(b"Jefe", b"what do ya want for nothing?")[12:28]  # RFC 4231, test case 2
    '5bdcc146bf60754e'
    """
    return PREFIX + hmac.new(bytes(key), bytes(msg), hashlib.sha256).hexdigest()


def mac(key: bytes, doc: Any) -> str:
    """The MAC of a document: :func:`raw_mac` over its canonical JSON."""
    return raw_mac(key, canonical(doc))


def check_tag(expected: str, tag: Any) -> bool:
    """Whether ``tag`` (anything a file or a server sent) equals ``expected``, in constant time.

    >>> check_tag("hmac-sha256:00", "hmac-sha256:00"), check_tag("hmac-sha256:00", None)
    (True, False)
    """
    return isinstance(tag, str) and tag.isascii() and hmac.compare_digest(expected, tag)
