"""Versioned metadata of an encrypted volume store (see docs/format.md)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from ..errors import CorruptStoreError

FORMAT_NAME = "hevr-encrypted-volume"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class ChannelInfo:
    """One encrypted channel: its fixed-point exponent and quantisation digits."""

    exponent: int
    digits: int | None = None  # None: stored exactly (integer volume)
    dims: int | None = None  # vector channel only

    def to_dict(self) -> dict:
        return {k: v for k, v in asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, d: dict) -> "ChannelInfo":
        return cls(exponent=int(d["exponent"]), digits=d.get("digits"), dims=d.get("dims"))


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
    base: int = 10
    complete: bool = False
    store_id: str = ""  # random per store creation: caches must not confuse two volumes at one path
    format: str = FORMAT_NAME
    version: int = FORMAT_VERSION
    extra: dict = field(default_factory=dict)

    @property
    def grid(self) -> tuple[int, int, int]:
        return tuple(math.ceil(s / b) for s, b in zip(self.shape, self.brick))  # type: ignore[return-value]

    @property
    def n_bricks(self) -> int:
        g = self.grid
        return g[0] * g[1] * g[2]

    def to_dict(self) -> dict[str, Any]:
        return {
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
            },
            "n_bricks": self.n_bricks,
            "complete": self.complete,
            "store_id": self.store_id,
            **({"extra": self.extra} if self.extra else {}),
        }

    @classmethod
    def from_dict(cls, d: Any, where: str = "store") -> "VolumeMetadata":
        if not isinstance(d, dict) or d.get("format") != FORMAT_NAME:
            raise CorruptStoreError(f"{where}: not an hevr encrypted volume (attribute 'hevr.format' is not {FORMAT_NAME!r})")
        if d.get("version") != FORMAT_VERSION:
            raise CorruptStoreError(
                f"{where}: unsupported format version {d.get('version')!r}; this hevr reads version {FORMAT_VERSION}"
            )
        try:
            ch = d["channels"]
            meta = cls(
                shape=tuple(int(x) for x in d["shape"]),
                spacing=tuple(float(x) for x in d["spacing"]),
                brick=tuple(int(x) for x in d["brick"]),
                n=str(d["public_key"]["n"]),
                fingerprint=str(d["public_key"]["fingerprint"]),
                ciphertext_bytes=int(d["ciphertext_bytes"]),
                dtype=str(d["dtype"]),
                value_range=tuple(float(x) for x in d["value_range"]),
                scalar=ChannelInfo.from_dict(ch["scalar"]) if "scalar" in ch else None,
                vector=ChannelInfo.from_dict(ch["vector"]) if "vector" in ch else None,
                base=int(d.get("base", 10)),
                complete=bool(d.get("complete", False)),
                store_id=str(d.get("store_id", "")),
                extra=dict(d.get("extra", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise CorruptStoreError(f"{where}: malformed metadata ({type(exc).__name__}: {exc})") from None
        if len(meta.shape) != 3 or len(meta.brick) != 3 or len(meta.spacing) != 3:
            raise CorruptStoreError(f"{where}: shape, brick and spacing must have 3 entries")
        if not meta.n.isdigit():
            raise CorruptStoreError(f"{where}: public_key.n must be a decimal string")
        return meta
