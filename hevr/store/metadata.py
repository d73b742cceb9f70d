"""Versioned, checksummed metadata of an encrypted volume store (see docs/format.md).

Version 2 adds integrity: the ``hevr`` attribute carries ``checksum``, the SHA-256 of its own
canonical JSON (every other field, keys sorted, no spaces), and every field is validated on
reading — types exactly (a bool is not an int, a float is not an int), ranges (brick >= 1, value
range ordered, known dtype), and consistency (fingerprint length, ``n_bricks`` and ``bits`` when
present). :meth:`VolumeMetadata.from_dict` names the first field that is wrong. Version 1 stores
(no digests) are refused with the command that converts them (``hevr upgrade-store``).

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
import re
from dataclasses import asdict, dataclass, field
from typing import Any

from ..core.validate import MAX_STORE_DIGITS, is_decimal
from ..crypto.tags import data_channel, tag_channel
from ..errors import CorruptStoreError
from ..volume.pyramid import MAX_LEVELS, level_brick, level_spacing
from .authenticity import is_auth
from .ome import ome_attribute  # noqa: F401 - re-exported: hevr.store.layout, hevr.store.pyramid
from .packing import PackingInfo, mantissa_range, store_span

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
DTYPES = (
    "bool",
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
    "float16",
    "float32",
    "float64",
)
MAX_N_DIGITS = 4300  # Python's int/str conversion limit (a 14 000-bit modulus): longer ones refused before int()
_HEX64 = re.compile(r"[0-9a-f]{64}")
_STORE_ID = re.compile(r"[0-9a-f]{16}")
_DOC_DIGEST = re.compile(r"sha256:[0-9a-f]{64}")
CHANNELS = ("scalar", "vector", "gradient")  # store order: the order of a brick's digests


def sha256_tag(data: bytes) -> str:
    """``"sha256:<hex>"``: how the metadata writes a digest (its checksum, the arrays' documents).

    >>> sha256_tag(b"")[:15]
    'sha256:e3b0c442'
    """
    return "sha256:" + hashlib.sha256(data).hexdigest()


def metadata_checksum(d: dict) -> str:
    """``"sha256:<hex>"`` of the canonical JSON of ``d`` without its ``checksum`` field.

    >>> metadata_checksum({"b": 1, "a": [1, 2]}) == metadata_checksum({"a": [1, 2], "b": 1, "checksum": "x"})
    True
    """
    body = {k: v for k, v in d.items() if k != "checksum"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return sha256_tag(text.encode())


@dataclass(frozen=True)
class ChannelInfo:
    """One encrypted channel: its fixed-point exponent and quantisation digits."""

    exponent: int
    digits: int | None = None  # None: stored exactly (integer volume)
    dims: int | None = None  # vector and gradient channels only

    def to_dict(self) -> dict:
        return {k: v for k, v in asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, d: Any, where: str = "store", name: str = "channels") -> ChannelInfo:
        if not isinstance(d, dict) or "exponent" not in d or set(d) - {"exponent", "digits", "dims"}:
            raise CorruptStoreError(
                f"{where}: {name}: expected an object with 'exponent' (and 'digits', 'dims'), got {d!r}"
            )
        exponent = _int(d["exponent"], f"{name}.exponent", where, -MAX_STORE_DIGITS, MAX_STORE_DIGITS)
        digits = _int(d["digits"], f"{name}.digits", where, 0, MAX_STORE_DIGITS) if "digits" in d else None
        dims = _int(d["dims"], f"{name}.dims", where, 2, 64) if "dims" in d else None
        if digits is not None and exponent != -digits:
            raise CorruptStoreError(f"{where}: {name}.exponent: expected -digits = {-digits}, got {exponent}")
        return cls(exponent=exponent, digits=digits, dims=dims)


@dataclass(frozen=True)
class LevelInfo:
    """One level of the encrypted multi-resolution pyramid (:mod:`hevr.store.pyramid`): its
    shape (``ceil`` halving of the level below), whether every brick is written, and the digests
    of its arrays' metadata documents (``levels/<level>/<array>``, relative names). A packed
    store's level (:mod:`hevr.store.packed_levels`, encrypted by the owner) has its own
    ``packing`` (written as ``layout``) and a brick whose packing-axis edge is a multiple of its slots."""

    level: int
    shape: tuple[int, int, int]
    brick: tuple[int, int, int]
    complete: bool = False
    arrays: dict = field(default_factory=dict)
    packing: PackingInfo | None = None

    def to_dict(self) -> dict:
        return {
            "level": self.level,
            "shape": list(self.shape),
            "brick": list(self.brick),
            "complete": self.complete,
            "arrays": dict(self.arrays),
            **({"layout": self.packing.to_dict()} if self.packing is not None else {}),
        }

    @classmethod
    def from_dict(
        cls,
        d: Any,
        where: str,
        expected_level: int,
        expected_shape: tuple,
        expected_brick: tuple,
        names: set,
        axis: int | None = None,
    ) -> LevelInfo:
        name = f"levels[{expected_level - 1}]"
        packed = axis is not None  # a packed store's level: its own layout, along the store's axis
        keys = {"level", "shape", "brick", "complete", "arrays"} | ({"layout"} if packed else set())
        if not isinstance(d, dict) or set(d) != keys:
            raise _bad(
                where,
                name,
                f"an object with {', '.join(repr(k) for k in sorted(keys))}"
                + (" (a packed store's level has its own layout)" if packed else ""),
                d,
            )
        _int(d["level"], f"{name}.level", where, expected_level, expected_level)
        shape = _triple(d["shape"], f"{name}.shape", where, "int")
        if shape != tuple(expected_shape):
            raise _bad(where, f"{name}.shape", f"{list(expected_shape)} (the level below, halved)", d["shape"])
        packing = PackingInfo.from_dict(d["layout"], f"{where}: {name}") if packed else None
        if packing is not None and packing.axis != axis:
            raise _bad(where, f"{name}.layout.axis", f"{axis} (the store's packing axis)", packing.axis)
        if packing is not None:  # the base brick, its packing-axis edge rounded up to the level's slots
            expected_brick = tuple(
                -(-b // packing.slots) * packing.slots if i == packing.axis else b for i, b in enumerate(expected_brick)
            )
        brick = _triple(d["brick"], f"{name}.brick", where, "int")
        if brick != tuple(expected_brick):
            raise _bad(
                where,
                f"{name}.brick",
                f"{list(expected_brick)} (hevr.volume.pyramid.level_brick"
                + (", its packing-axis edge a multiple of the level's slots)" if packed else ")"),
                d["brick"],
            )
        if type(d["complete"]) is not bool:
            raise _bad(where, f"{name}.complete", "true or false", d["complete"])
        arrays = d["arrays"]
        if not (
            isinstance(arrays, dict)
            and set(arrays) == names
            and all(isinstance(v, str) and _DOC_DIGEST.fullmatch(v) for v in arrays.values())
        ):
            raise _bad(where, f"{name}.arrays", f"a 'sha256:…' digest for each of {sorted(names)}", arrays)
        return cls(
            level=expected_level, shape=shape, brick=brick, complete=d["complete"], arrays=dict(arrays), packing=packing
        )


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
    extra: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)  # array name -> "sha256:…" of its zarr.json bytes (v2)
    levels: tuple = ()  # LevelInfo of pyramid levels 1, 2, … (hevr.store.pyramid); () without a pyramid
    # {"frame": "RAS", "origin": [x, y, z]} when the input recorded patient geometry (hevr.read_scan), else {}
    patient: dict = field(default_factory=dict)
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
        spacing ``2^level·s``, its bricks (:func:`~hevr.volume.pyramid.level_brick`), the key, channel exponents ``e − 3·level``
        (mantissas are 125·Σ of 8 children per level: :mod:`hevr.volume.pyramid`) and the
        level's own array digests and completeness; a packed store's level its own packing
        (:mod:`hevr.store.packed_levels`). Its voxel (0, 0, 0) sits at
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
        return _parse(cls, d, where, version)


# -- field validation ---------------------------------------------------------------------------
def _bad(where: str, name: str, expected: str, got: Any) -> CorruptStoreError:
    text = repr(got)
    return CorruptStoreError(f"{where}: {name}: expected {expected}, got {text[:80] + '…' if len(text) > 80 else text}")


def _get(d: dict, key: str, where: str, prefix: str = "") -> Any:
    if key not in d:
        raise CorruptStoreError(f"{where}: malformed metadata (missing field '{prefix}{key}')")
    return d[key]


def _int(v: Any, name: str, where: str, lo: int, hi: int | None = None) -> int:
    if type(v) is not int or v < lo or (hi is not None and v > hi):
        raise _bad(where, name, f"an integer in [{lo}, {hi if hi is not None else '∞'}]", v)
    return v


def _number(v: Any, name: str, where: str, positive: bool = False) -> float:
    if type(v) not in (int, float) or not math.isfinite(v) or (positive and not v > 0):
        raise _bad(where, name, "a positive finite number" if positive else "a finite number", v)
    return float(v)


def _triple(v: Any, name: str, where: str, kind: str) -> tuple:
    if not isinstance(v, list) or len(v) != 3:
        raise _bad(where, name, "a list of 3 entries", v)
    if kind == "int":
        return tuple(_int(x, name, where, 1) for x in v)
    return tuple(_number(x, name, where, positive=True) for x in v)


def _parse(cls: type, d: dict, where: str, version: int) -> VolumeMetadata:
    shape = _triple(_get(d, "shape", where), "shape", where, "int")
    spacing = _triple(_get(d, "spacing", where), "spacing", where, "float")
    brick = _triple(_get(d, "brick", where), "brick", where, "int")
    pk = _get(d, "public_key", where)
    if not isinstance(pk, dict):
        raise _bad(where, "public_key", "an object", pk)
    n = _get(pk, "n", where, "public_key.")
    if not (is_decimal(n, MAX_N_DIGITS) and n[0] != "0"):
        raise _bad(
            where,
            "public_key.n",
            f"a decimal string of at most {MAX_N_DIGITS} digits (public_key.n must be a decimal string)",
            n,
        )
    fingerprint = _get(pk, "fingerprint", where, "public_key.")
    if not (isinstance(fingerprint, str) and _HEX64.fullmatch(fingerprint)):
        raise _bad(where, "public_key.fingerprint", "64 lower-case hex digits", fingerprint)
    if "bits" in pk and pk["bits"] != int(n).bit_length():
        raise _bad(where, "public_key.bits", f"{int(n).bit_length()} (the bit length of n)", pk["bits"])
    width = _int(_get(d, "ciphertext_bytes", where), "ciphertext_bytes", where, 1)
    dtype = _get(d, "dtype", where)
    if dtype not in DTYPES:
        raise _bad(where, "dtype", f"one of {', '.join(DTYPES)}", dtype)
    vr = _get(d, "value_range", where)
    if not isinstance(vr, list) or len(vr) != 2:
        raise _bad(where, "value_range", "a list [lo, hi]", vr)
    lo, hi = (_number(x, "value_range", where) for x in vr)
    if not lo < hi:
        raise _bad(where, "value_range", "lo < hi", vr)
    base = d.get("base", 10)
    if type(base) is not int or base != 10:
        raise _bad(where, "base", "10", base)
    ch = _get(d, "channels", where)
    if not isinstance(ch, dict) or not (set(ch) & {"scalar", "vector"}) or set(ch) - set(CHANNELS):
        raise _bad(where, "channels", "an object with 'scalar' and/or 'vector' (and 'gradient')", ch)
    scalar = ChannelInfo.from_dict(ch["scalar"], where, "channels.scalar") if "scalar" in ch else None
    vector = ChannelInfo.from_dict(ch["vector"], where, "channels.vector") if "vector" in ch else None
    if vector is not None and (vector.dims is None or vector.digits is None):
        raise _bad(where, "channels.vector", "'digits' and 'dims'", ch["vector"])
    gradient = ChannelInfo.from_dict(ch["gradient"], where, "channels.gradient") if "gradient" in ch else None
    if gradient is not None and (vector is None or gradient != vector):
        raise _bad(
            where, "channels.gradient", "the same 'exponent', 'digits' and 'dims' as channels.vector", ch["gradient"]
        )
    complete = d.get("complete", False)
    if type(complete) is not bool:
        raise _bad(where, "complete", "true or false", complete)
    store_id = d.get("store_id", "")
    if not isinstance(store_id, str) or (version >= 2 and not _STORE_ID.fullmatch(store_id)):
        raise _bad(where, "store_id", "16 lower-case hex digits", store_id)
    extra = d.get("extra", {})
    if not isinstance(extra, dict):
        raise _bad(where, "extra", "an object", extra)
    patient = _patient(d.get("patient", {}), where)
    tags = d.get("tags", False)
    if type(tags) is not bool:
        raise _bad(where, "tags", "true or false", tags)
    auth = d.get("auth", "")
    if (tags or "auth" in d) and not (tags and is_auth(auth)):
        raise _bad(
            where,
            "auth",
            "the owner's MAC 'hmac-sha256:<64 hex>' on a verifiable store (tags: true) and "
            "nothing else (a verifiable store written before hevr bound its metadata: encrypt it again)",
            auth,
        )
    arrays = d.get("arrays", {})
    names = {*(k for k in CHANNELS if k in ch), *(tag_channel(k) for k in CHANNELS if k in ch and tags), "done"}
    if version >= 2 and not (
        isinstance(arrays, dict)
        and set(arrays) == names
        and all(isinstance(v, str) and _DOC_DIGEST.fullmatch(v) for v in arrays.values())
    ):
        raise _bad(where, "arrays", f"a 'sha256:…' digest for each of {sorted(names)}", arrays)
    meta = cls(
        shape=shape,
        spacing=spacing,
        brick=brick,
        n=n,
        fingerprint=fingerprint,
        ciphertext_bytes=width,
        dtype=dtype,
        value_range=(lo, hi),
        scalar=scalar,
        vector=vector,
        gradient=gradient,
        base=base,
        complete=complete,
        store_id=store_id,
        version=version,
        extra=dict(extra),
        arrays=dict(arrays) if version >= 2 else {},
        patient=patient,
        tags=tags,
        auth=auth,
    )
    if "layout" in d:
        meta = dataclasses.replace(meta, packing=_packing(d, meta, where))
    levels = d.get("levels", [])
    if not isinstance(levels, list) or len(levels) > MAX_LEVELS:
        raise _bad(where, "levels", f"a list of at most {MAX_LEVELS} pyramid levels", levels)
    parsed, below = [], shape
    for i, lv in enumerate(levels):
        below = tuple(-(-s // 2) for s in below)
        info = LevelInfo.from_dict(
            lv,
            where,
            i + 1,
            below,
            level_brick(brick, i + 1),
            names,
            None if meta.packing is None else meta.packing.axis,
        )
        if info.packing is not None:  # checked as level 0's: against the level's shape, exponent and key
            _level_packing(meta, info, where)
        parsed.append(info)
    if parsed:
        meta = dataclasses.replace(meta, levels=tuple(parsed))
    if "n_bricks" in d and d["n_bricks"] != meta.n_bricks:
        raise _bad(where, "n_bricks", f"{meta.n_bricks} (the brick grid of shape and brick)", d["n_bricks"])
    return meta


def _packing(d: dict, meta: VolumeMetadata, where: str) -> PackingInfo:
    """A packed store's ``layout``, checked against the rest: the scalar (and vector, gradient, packed
    alike: :func:`~hevr.store.packing.store_span`) channel, the value range's offset, slots that fit
    the key and brick, a slot width for every frame's largest sum (:meth:`PackingInfo.check`)."""
    packing = PackingInfo.from_dict(d["layout"], where)
    if meta.scalar is None:
        raise _bad(where, "channels", "'scalar' (and 'vector', 'gradient') in a packed store", d.get("channels"))
    if meta.vector is not None and d.get("levels"):  # the owner encrypts a packed store's levels: scalar only
        raise _bad(where, "levels", "none in a packed store with the vector channel", "a list of levels")
    lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
    if packing.offset != lo:
        raise _bad(where, "layout.offset", f"{lo} (the lowest mantissa of value_range)", str(packing.offset))
    span = store_span(hi - lo, None if meta.vector is None else meta.vector.digits)
    packing.check(int(meta.n).bit_length(), meta.shape, meta.brick, span, where)
    return packing


def _level_packing(meta: VolumeMetadata, info: LevelInfo, where: str) -> None:
    """A packed level's ``layout`` (:mod:`hevr.store.packed_levels`; its axis checked on parsing): the offset
    at the level's exponent e − 3·level, slots for the key and brick, a width for the level's largest sum."""
    name = f"levels[{info.level - 1}].layout"
    packing = info.packing
    lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent - 3 * info.level)
    if packing.offset != lo:
        raise _bad(
            where,
            f"{name}.offset",
            f"{lo} (the lowest mantissa of value_range at the level's exponent)",
            str(packing.offset),
        )
    packing.check(int(meta.n).bit_length(), info.shape, info.brick, hi - lo, f"{where}: {name}")


def _patient(p: Any, where: str) -> dict:
    """The optional ``patient`` object: the frame the volume is in (only ``"RAS"``) and the
    world position (mm) of voxel (0, 0, 0); both public header facts of the input file.

    >>> _patient({"frame": "RAS", "origin": [-50.5, -46, -80.5]}, "store")
    {'frame': 'RAS', 'origin': (-50.5, -46.0, -80.5)}
    """
    if p == {}:
        return {}
    if not (
        isinstance(p, dict)
        and set(p) == {"frame", "origin"}
        and p["frame"] == "RAS"
        and isinstance(p["origin"], list)
        and len(p["origin"]) == 3
    ):
        raise _bad(where, "patient", '{"frame": "RAS", "origin": [x, y, z]}', p)
    origin = tuple(_number(v, "patient.origin", where) for v in p["origin"])
    return {"frame": "RAS", "origin": origin}
