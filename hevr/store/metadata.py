"""Versioned, checksummed metadata of an encrypted volume store (see docs/format.md).

Version 2 adds integrity: the ``hevr`` attribute carries ``checksum``, the SHA-256 of its own
canonical JSON (every other field, keys sorted, no spaces), and every field is validated on
reading — types exactly (a bool is not an int, a float is not an int), ranges (brick >= 1, value
range ordered, known dtype), and consistency (fingerprint length, ``n_bricks`` and ``bits`` when
present). :meth:`VolumeMetadata.from_dict` names the first field that is wrong. Version 1 stores
(no digests) are refused with the command that converts them (``hevr upgrade-store``).
The parts live in :mod:`hevr.store.metadata_parts` (a channel, a pyramid level), the field readers
in :mod:`hevr.store.metadata_fields`, the strict reading of a whole attribute in
:mod:`hevr.store.metadata_parse`.

>>> m = VolumeMetadata(shape=(2, 2, 2), spacing=(1.0, 1.0, 1.0), brick=(2, 2, 2), n="3233",
...                    fingerprint="ab" * 32, ciphertext_bytes=3, dtype="uint8",
...                    value_range=(0.0, 255.0), scalar=ChannelInfo(0), vector=None,
...                    complete=True, store_id="0123456789abcdef",
...                    arrays={"scalar": "sha256:" + "0" * 64, "done": "sha256:" + "1" * 64})
>>> VolumeMetadata.from_dict(m.to_dict()) == m
True
>>> d = m.to_dict(); d["shape"] = [2, 2, 3]
>>> VolumeMetadata.from_dict(d)
Traceback (most recent call last):
    ...
hevr.errors.CorruptStoreError: store: metadata checksum mismatch (the 'hevr' attribute was modified or corrupted)
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

from ..crypto.tags import data_channel, tag_channel
from ..errors import CorruptStoreError
from ..volume.pyramid import level_spacing
from .metadata_fields import CHANNELS
from .metadata_parse import parse_metadata
from .metadata_parts import ChannelInfo, LevelInfo
from .ome import ome_attribute  # noqa: F401 - re-exported: hevr.store.layout, hevr.store.pyramid
from .packing import PackingInfo

__all__ = [
    "CHANNELS",
    "ChannelInfo",
    "LevelInfo",
    "VolumeMetadata",
    "ome_attribute",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "metadata_checksum",
    "sha256_tag",
]

FORMAT_NAME = "hevr-encrypted-volume"
FORMAT_VERSION = 2


def sha256_tag(data: bytes) -> str:
    """``"sha256:<hex>"``: how the metadata writes a digest (its checksum, the arrays' documents).

    >>> sha256_tag(b"")[:15]
    'sha256:e3b0c442'
    """
    return "sha256:" + hashlib.sha256(data).hexdigest()


def metadata_checksum(d: dict[str, Any]) -> str:
    """``"sha256:<hex>"`` of the canonical JSON of ``d`` without its ``checksum`` field.

    >>> metadata_checksum({"b": 1, "a": [1, 2]}) == metadata_checksum({"a": [1, 2], "b": 1, "checksum": "x"})
    True
    """
    body = {k: v for k, v in d.items() if k != "checksum"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return sha256_tag(text.encode())


@dataclass(frozen=True)
class VolumeMetadata:
    """Everything public about an encrypted volume. Never holds secret-key material."""

    shape: tuple[int, int, int]
    spacing: tuple[float, float, float]  # world order (sx, sy, sz)
    brick: tuple[int, int, int]  # array order (bz, by, bx)
    n: str  # public modulus, decimal string
    fingerprint: str
    ciphertext_bytes: int
    dtype: str
    value_range: tuple[float, float]
    scalar: ChannelInfo | None
    vector: ChannelInfo | None
    gradient: ChannelInfo | None = None  # g·e(d), hevr.volume.gradient: same dims and digits as vector
    base: int = 10
    complete: bool = False
    store_id: str = ""  # random per store creation: digests and caches tell two volumes apart by it
    format: str = FORMAT_NAME
    version: int = FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)
    arrays: dict[str, str] = field(default_factory=dict)  # array name -> "sha256:…" of its zarr.json bytes (v2)
    levels: tuple[LevelInfo, ...] = ()  # LevelInfo of pyramid levels 1, 2, … (hevr.store.pyramid); () without a pyramid
    # {"frame": "RAS", "origin": [x, y, z]} when the input recorded patient geometry (hevr.read_scan), else {}
    patient: dict[str, Any] = field(default_factory=dict)
    # a tag channel "<c>_tag" beside every channel c (encrypt_volume(verifiable=True), hevr.crypto.tags)
    tags: bool = False
    # the owner's MAC over the fields that shape a picture (hevr.store.authenticity); verifiable stores only
    auth: str = ""
    # a slot-packed store (hevr.store.packing): S voxels along one axis per ciphertext; None: one per voxel
    packing: PackingInfo | None = None

    @property
    def layout(self) -> str:
        """``"packed"`` (:mod:`hevr.store.packing`) or ``"voxel"`` (one ciphertext per voxel)."""
        return "voxel" if self.packing is None else "packed"

    @property
    def grid(self) -> tuple[int, int, int]:
        return tuple(math.ceil(s / b) for s, b in zip(self.shape, self.brick))  # type: ignore[return-value]

    @property
    def n_bricks(self) -> int:
        g = self.grid
        return g[0] * g[1] * g[2]

    def level_meta(self, level: int) -> VolumeMetadata:
        """The metadata of pyramid level ``level`` (≥ 1) as a volume of its own: the level's shape,
        spacing ``2^level·s``, its bricks (:func:`~hevr.volume.pyramid.level_brick`), the key,
        channel exponents ``e − 3·level`` (mantissas are 125·Σ of 8 children per level:
        :mod:`hevr.volume.pyramid`) and the level's own array digests and completeness; a packed
        store's level its own packing (:mod:`hevr.store.packed_levels`). Its voxel (0, 0, 0) sits at
        :func:`hevr.volume.pyramid.level_origin`, not at the world origin."""
        info = self.levels[level - 1]

        def shifted(ch: ChannelInfo | None) -> ChannelInfo | None:
            if ch is None:
                return None
            digits = None if ch.digits is None else ch.digits + 3 * level
            return ChannelInfo(exponent=ch.exponent - 3 * level, digits=digits, dims=ch.dims)

        return dataclasses.replace(
            self,
            shape=info.shape,
            brick=info.brick,
            spacing=level_spacing(self.spacing, level),
            scalar=shifted(self.scalar),
            vector=shifted(self.vector),
            gradient=shifted(self.gradient),
            complete=info.complete,
            arrays=dict(info.arrays),
            levels=(),
            packing=info.packing,
        )

    @property
    def data_channels(self) -> tuple[str, ...]:
        """The channels of encrypted values present, in store order (scalar, vector, gradient)."""
        return tuple(name for name in CHANNELS if getattr(self, name) is not None)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Every stored channel in store order, the order of the digests: the data channels, then
        (a verifiable store) their tag channels ``<c>_tag`` in the same order."""
        data = self.data_channels
        return data + tuple(tag_channel(c) for c in data) if self.tags else data

    def components(self, channel: str) -> int:
        """Ciphertexts per voxel of ``channel``: 1 (scalar) or its ``dims`` (vector, gradient); a tag
        channel has its channel's."""
        channel = data_channel(channel)
        return 1 if channel == "scalar" else int(getattr(self, channel).dims)

    def to_dict(self) -> dict[str, Any]:
        d = {
            "format": self.format,
            "version": self.version,
            "shape": list(self.shape),
            "spacing": list(self.spacing),
            "brick": list(self.brick),
            "public_key": {"n": self.n, "bits": int(self.n).bit_length(), "fingerprint": self.fingerprint},
            "ciphertext_bytes": self.ciphertext_bytes,
            "dtype": self.dtype,
            "value_range": list(self.value_range),
            "base": self.base,
            "channels": {
                **({"scalar": self.scalar.to_dict()} if self.scalar else {}),
                **({"vector": self.vector.to_dict()} if self.vector else {}),
                **({"gradient": self.gradient.to_dict()} if self.gradient else {}),
            },
            "n_bricks": self.n_bricks,
            "complete": self.complete,
            "store_id": self.store_id,
            **({"extra": self.extra} if self.extra else {}),
            **({"arrays": dict(self.arrays)} if self.arrays else {}),
            **({"levels": [lv.to_dict() for lv in self.levels]} if self.levels else {}),
            **(
                {"patient": {"frame": self.patient["frame"], "origin": list(self.patient["origin"])}}
                if self.patient
                else {}
            ),
            **({"tags": True} if self.tags else {}),
            **({"auth": self.auth} if self.auth else {}),
            **({"layout": self.packing.to_dict()} if self.packing is not None else {}),
        }
        if self.version >= 2:
            d["checksum"] = metadata_checksum(d)
        return d

    @classmethod
    def from_dict(cls, d: Any, where: str = "store", *, accept_v1: bool = False) -> VolumeMetadata:
        """Parse and validate the ``hevr`` attribute; :class:`hevr.CorruptStoreError` names
        the first field that is wrong. ``accept_v1`` (for ``hevr upgrade-store`` only) also
        reads version 1, which has no checksum and no digests."""
        if not isinstance(d, dict) or d.get("format") != FORMAT_NAME:
            raise CorruptStoreError(
                f"{where}: not an hevr encrypted volume (attribute 'hevr.format' is not {FORMAT_NAME!r})"
            )
        version = d.get("version")
        if version == 1 and type(version) is int and not accept_v1:
            raise CorruptStoreError(
                f"{where}: format version 1 has no integrity digests and is no longer opened; convert it once "
                f"with: hevr upgrade-store {where} NEW.zarr"
            )
        if not (type(version) is int and (version == FORMAT_VERSION or (accept_v1 and version == 1))):
            raise CorruptStoreError(
                f"{where}: unsupported format version {version!r}; this hevr reads version {FORMAT_VERSION}"
            )
        if version >= 2 and d.get("checksum") != metadata_checksum(d):
            what = "missing" if "checksum" not in d else "mismatch (the 'hevr' attribute was modified or corrupted)"
            raise CorruptStoreError(f"{where}: metadata checksum {what}")
        return parse_metadata(cls, d, where, version)
