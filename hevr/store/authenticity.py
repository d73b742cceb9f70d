"""The owner's MAC over a verifiable store's metadata (issue 38): what turns ciphertexts into a picture.

The tags (:mod:`hevr.crypto.tags`) prove *which mantissas* a frame sums — per voxel, channel, level
and store id. Everything that turns those sums into a picture is public metadata: the shape and
spacing (the rays), the brick grid, each channel's exponent and digits (the scale of every pixel),
the value range (the transfer-function presets and the default window), the patient frame, the key.
A server that edits them and recomputes the keyless checksum would otherwise get a wrong picture
accepted as "verified". So the owner, who holds the private key when it writes a verifiable store,
binds them with a MAC under a key derived from the tag key:

    auth = HMAC-SHA256(K_meta, canonical JSON of the fields below),
    K_meta = HMAC-SHA256(k, "hevr-metadata-mac-v1")            (k: the tag key's PRF key)

and the key holder recomputes it before any pixel of a verified render is returned
(:meth:`hevr.rendering.verification.Verification.check`). Bound (:data:`AUTHENTICATED`): shape, spacing,
brick, the key (n, fingerprint, record width), dtype, value range, base, the channels (exponent,
digits, dims), the store id, the patient frame and origin, the tags flag and, for a packed store,
its ``layout`` (axis, slots, slot bits, weight bits, offset: :mod:`hevr.store.packing`) and its pyramid
levels' layouts (``level_layouts``, level 1, 2, …: :mod:`hevr.store.packed_levels`). Not bound, because
they are derived from the bound fields and checked on reading (:mod:`hevr.store.metadata`), or carry
no meaning for a picture: the pyramid levels' shapes and bricks (halvings of the shape, checked;
their exponents e − 3·level and their tags 125 ⊗ the children's are fixed by the scheme), the
completeness flag and the arrays' document digests (storage integrity, re-checked on every read).

Canonical form: ``json.dumps(fields, sort_keys=True, separators=(",", ":"), ensure_ascii=True)`` of
the values as :meth:`~hevr.store.metadata.VolumeMetadata.to_dict` writes them (floats as Python's
shortest repr, which reads back to the same float).

>>> d = {"shape": [2, 2, 2], "spacing": [1.0, 1.0, 2.0], "brick": [2, 2, 2],
...      "public_key": {"n": "3233", "bits": 12, "fingerprint": "ab" * 32}, "ciphertext_bytes": 3,
...      "dtype": "uint8", "value_range": [0.0, 255.0], "base": 10, "channels": {"scalar": {"exponent": 0}},
...      "store_id": "0123456789abcdef", "tags": True, "complete": False}
>>> sorted(authenticated_fields(d))[:4], "complete" in authenticated_fields(d)
(['base', 'brick', 'channels', 'ciphertext_bytes'], False)
>>> mac = raw_metadata_mac(bytes(32), authenticated_fields(d))
>>> mac.startswith("hmac-sha256:") and len(mac) == 12 + 64
True
>>> d2 = dict(d, spacing=[1.0, 1.0, 4.0])
>>> raw_metadata_mac(bytes(32), authenticated_fields(d2)) == mac
False
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

from ..crypto.mac import PREFIX, check_tag, derive_key, digest, mac
from ..crypto.tags import tag_key_of

__all__ = [
    "AUTHENTICATED",
    "AUTH_PREFIX",
    "authenticated_fields",
    "check_metadata_mac",
    "is_auth",
    "metadata_digest",
    "metadata_mac",
    "raw_metadata_mac",
]

AUTH_PREFIX = PREFIX
_AUTH = re.compile(r"hmac-sha256:[0-9a-f]{64}")
# the fields of the metadata (VolumeMetadata.to_dict's names) that the owner's MAC binds
AUTHENTICATED = (
    "shape",
    "spacing",
    "brick",
    "public_key",
    "ciphertext_bytes",
    "dtype",
    "value_range",
    "base",
    "channels",
    "store_id",
    "patient",
    "tags",
)


def is_auth(value: Any) -> bool:
    """Whether ``value`` is a MAC as the metadata writes it (``"hmac-sha256:<64 hex>"``).

    >>> is_auth("hmac-sha256:" + "0" * 64), is_auth("sha256:" + "0" * 64), is_auth(None)
    (True, False, False)
    """
    return isinstance(value, str) and _AUTH.fullmatch(value) is not None


def authenticated_fields(d: dict[str, Any]) -> dict[str, Any]:
    """The bound fields of a metadata dict (``to_dict``'s form; absent optional ones as their defaults)."""
    out = {name: d.get(name) for name in AUTHENTICATED}
    out["patient"] = d.get("patient") or {}
    out["tags"] = bool(d.get("tags", False))
    out["base"] = d.get("base", 10)
    pk = d.get("public_key") or {}
    out["public_key"] = {"n": pk.get("n"), "fingerprint": pk.get("fingerprint")}
    if d.get("layout") is not None:  # a packed store's slots (absent, as in every store before them, for per-voxel)
        out["layout"] = d["layout"]
    levels = d.get("levels")
    levels = levels if isinstance(levels, list) else []
    layouts = [lv["layout"] for lv in levels if isinstance(lv, dict) and "layout" in lv]
    if layouts:  # a packed store's levels' slots, level 1, 2, … (the owner encrypted them: hevr.store.packed_levels)
        out["level_layouts"] = layouts
    return out


def metadata_digest(fields: dict) -> str:
    """``"sha256:<hex>"`` of the canonical bound fields: what the key holder's known-stores file
    remembers of a store (:mod:`hevr.store.known`), with or without a MAC.

    >>> metadata_digest({"a": 1}) == metadata_digest({"a": 1}), metadata_digest({"a": 1})[:7]
    (True, 'sha256:')
    """
    return "sha256:" + digest(fields).hex()


def raw_metadata_mac(prf_key: bytes, fields: dict) -> str:
    """The MAC of the bound ``fields`` under the tag key's PRF key (module docstring)."""
    return mac(derive_key(prf_key, b"hevr-metadata-mac-v1"), fields)


def metadata_mac(private_key: Any, fields: dict) -> str:
    """The owner's MAC of the bound ``fields`` (:func:`raw_metadata_mac` under the private key's tag key)."""
    return raw_metadata_mac(tag_key_of(private_key).prf_key, fields)


def check_metadata_mac(private_key: Any, fields: dict, auth: Any) -> bool:
    """Whether ``auth`` is the owner's MAC of ``fields`` (constant-time comparison)."""
    if not is_auth(auth):
        return False
    return check_tag(metadata_mac(private_key, fields), auth)


def authenticate(meta: Any, key: Any) -> Any:
    """A verifiable store's metadata with the owner's MAC over what shapes a picture; other
    stores' unchanged (the writer's and the packed levels' one home for it)."""
    if not meta.tags:
        return meta
    return dataclasses.replace(meta, auth=metadata_mac(key, authenticated_fields(meta.to_dict())))
