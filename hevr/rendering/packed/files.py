"""Packed frames as files: :func:`save_packed` / :func:`packed_bytes` write a :class:`PackedImage`,
:func:`parse_packed` reads one back (``hevr.load_image`` dispatches here on the magic).

A packed frame file is a ``.hevr`` file whose magic says "packed" (``HEVRIMG`` then ``P``, then a
version byte), so that everything that tells a frame from other files by ``HEVRIMG`` (``hevr
decrypt``, ``hevr info``) takes it for one; :func:`hevr.load_image` returns a
:class:`~hevr.rendering.packed.image.PackedImage` for it and an
:class:`~hevr.image.EncryptedImage` for any other frame. Layout (``docs/format.md``, "Packed
frame files")::

    magic (9) | L: uint32 LE | JSON header (L) | records: Σ counts × width bytes | SHA-256 (32)

The header holds only what the key holder cannot recompute: the camera, sampling, weight bits,
tile, pyramid level, the store's metadata (``VolumeMetadata.to_dict``, with the owner's MAC on a
verifiable store) and the records per tile; a verified frame's record (aggregate, seed) with the
key holder's stamp (:mod:`hevr.image.stamp`). The reader rebuilds the frame's
:class:`~hevr.rendering.packed.plan.SlicePlan` from them, as :func:`hevr.render` planned it, and
derives the exponent, offset and span from the metadata; every count must be the plan's.

Everything in a file is untrusted: parsed as JSON data with bounds (containers, strings,
integer digits, nesting: :func:`hevr.image.header.parse_json`; the header's length against the
file's), every field checked before anything sized by it is built (the camera against the render
size limits before the plan). The SHA-256 trailer is checked first: a truncated file or a flipped
bit is a :class:`hevr.IntegrityError`, as is any field that is wrong (a file that checks out but
was written by hand); another magic is a :class:`hevr.CorruptStoreError` (not a packed frame).
"""

from __future__ import annotations

import hashlib
import json
import logging
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ...core.magic import IMAGE_MAGIC_PREFIX
from ...core.validate import check_bool
from ...crypto.paillier import fingerprint as fingerprint_of
from ...crypto.records import record_width
from ...errors import CorruptStoreError, HevrError, IntegrityError, ParameterError
from ...image.header import parse_json
from ...image.proof import Expect
from ...image.provenance import for_file as keep_record
from ...image.stamp import STAMP_FIELDS, read_stamp, saved_name, stamp_header
from ...store.metadata import VolumeMetadata
from ...store.packing import MAX_WEIGHT_BITS, mantissa_range
from ...store.paths import check_storage_options, output_location, write_output
from ...volume.pyramid import MAX_LEVELS
from ..geometry.camera import Camera
from ..planning.planner import check_render_size
from .plan import SlicePlan

log = logging.getLogger(__name__)

__all__ = [
    "FORMAT",
    "MAGIC",
    "MAGIC_PREFIX",
    "VERSION",
    "check_packed",
    "is_packed_frame",
    "packed_bytes",
    "parse_packed",
    "save_packed",
]

MAGIC_PREFIX = IMAGE_MAGIC_PREFIX + b"P"  # a frame file ("HEVRIMG"), packed ("P")
VERSION = 1
MAGIC = MAGIC_PREFIX + bytes([VERSION])
FORMAT = "hevr-packed-frame"
LENGTH = struct.Struct("<I")
HEAD = len(MAGIC) + LENGTH.size
DIGEST_BYTES = 32
MAX_HEADER = 1 << 22  # 4 MiB: the metadata, camera and one count per tile take a few KiB
MAX_TILE = 4096  # SlicePlan.build's bound
FIELDS = frozenset({"format", "version", "camera", "sampling", "weight_bits", "tile", "level", "metadata", "counts"})
OPTIONAL = frozenset({"verification", *STAMP_FIELDS, "channel"})
COLOUR_CHANNELS = ("vector", "gradient")  # a colour frame's components (absent: the scalar X-ray)
RECORD = frozenset({"aggregate", "seed"})
_BAD = (HevrError, TypeError, ValueError, OverflowError)  # what a hand-made field may raise on the way


def is_packed_frame(head: bytes) -> bool:
    """Whether bytes begin like a packed frame file (any version).

    >>> is_packed_frame(MAGIC + b"..."), is_packed_frame(b"HEVRIMG\\x03...")
    (True, False)
    """
    return bytes(head[: len(MAGIC_PREFIX)]) == MAGIC_PREFIX


# -- writing ------------------------------------------------------------------------------------
def frame_metadata(img: Any) -> tuple[VolumeMetadata, VolumeMetadata]:
    """(the store's metadata, the frame's: its pyramid level's) of a packed frame."""
    meta = img.meta if img.meta is not None else getattr(img.verification, "meta", None)
    if meta is None:
        raise ParameterError(
            "image: expected a packed frame that keeps its store's metadata (one hevr.render "
            "returned), got one without it; render it again"
        )
    level = int(img.level)
    return meta, (meta.level_meta(level) if level else meta)


def check_packed(img: Any) -> None:
    """Raise :class:`hevr.IntegrityError` for a frame that decryption would refuse on its shape
    alone: another number of tiles or records per tile than its plan, records that are not
    (values, width) uint8."""
    plan = img.plan
    _, fm = frame_metadata(img)
    width = int(fm.ciphertext_bytes)
    k = len(getattr(img, "components", [img]))  # a colour frame: k components' tiles, component-major
    if len(img.ciphertexts) != k * plan.n_tiles:
        raise IntegrityError(f"image: expected {k * plan.n_tiles} tiles (its plan's), got {len(img.ciphertexts)}")
    for i, recs in enumerate(img.ciphertexts):
        t = i % plan.n_tiles
        j0, j1, b0, b1 = plan.tile_bounds(t)
        want = (j1 - j0) * (b1 - b0)
        a = np.asarray(recs)
        if a.dtype != np.uint8 or a.shape != (want, width):
            raise IntegrityError(f"image: tile {t}: expected ({want}, {width}) uint8 records, got {a.shape} {a.dtype}")


def _header(img: Any) -> dict:
    meta, fm = frame_metadata(img)
    plan = img.plan
    head = {
        "format": FORMAT,
        "version": VERSION,
        "camera": img.camera.to_dict(),
        "sampling": plan.sampling,
        "weight_bits": int(plan.weight_bits),
        "tile": int(plan.tile),
        "level": int(img.level),
        "metadata": meta.to_dict(),
        "counts": [int(len(c)) for c in img.ciphertexts],
    }
    channel = getattr(img, "channel", "scalar") if hasattr(img, "components") else "scalar"
    if channel != "scalar":
        head["channel"] = channel
    v = img.verification
    if v is not None:
        if (
            v.meta.to_dict() != meta.to_dict()
            or int(v.level) != int(img.level)
            or getattr(v, "channel", "scalar") != channel
        ):
            raise ParameterError(
                "image: its verification record is of another store or level than the frame; render it again"
            )
        head["verification"] = {"aggregate": str(int(v.aggregate)), "seed": bytes(v.seed).hex()}
    return head


def file_parts(img: Any, private_key: Any = None, saved_as: str = "") -> list:
    """The file's bytes before its SHA-256 trailer: magic, header length, header, records. A
    verified frame is stamped with ``private_key`` (whose holder checked it), else keeps the
    stamp it was read with (bound to ``saved_as``, the file's name)."""
    header = _header(img)
    body = [np.ascontiguousarray(c, dtype=np.uint8).reshape(-1) for c in img.ciphertexts]
    stamp_header(header, body, img, private_key, saved_as)
    head = json.dumps(header, separators=(",", ":"), ensure_ascii=True).encode()
    if len(head) > MAX_HEADER:
        raise ParameterError(f"image: expected a header of at most {MAX_HEADER} bytes, got {len(head)}")
    return [MAGIC, LENGTH.pack(len(head)), head, *body]


def for_file(img: Any, private_key: Any) -> Any:
    """The frame as a file holds it: checked; a verified one checked now with the key (and
    stamped), or, drawn here and saved without the key, without its record (a warning)."""
    check_packed(img)
    return keep_record(img, private_key, lambda key: img.decrypt_sums(key, require_verified=Expect(moved=True)))


def save_packed(
    img: Any, path: str | Path, *, overwrite: bool = False, storage_options: dict | None = None, private_key: Any = None
) -> None:
    """Write ``img`` to ``path`` (:meth:`hevr.PackedImage.save`: atomic, never over a file unless
    ``overwrite``; an fsspec URL in one request)."""
    so = check_storage_options(storage_options)
    overwrite = check_bool("overwrite", overwrite)
    where = output_location(path)
    out = for_file(img, private_key)
    write_output(
        where,
        file_parts(out, private_key, saved_name(where)),
        so,
        overwrite=overwrite,
        doing="writing the packed frame",
    )


def packed_bytes(img: Any, private_key: Any = None) -> bytes:
    """The file's bytes (:func:`save_packed`'s, with no name under a stamp)."""
    parts = file_parts(for_file(img, private_key), private_key)
    digest = hashlib.sha256()
    for part in parts:
        digest.update(part)
    return b"".join(bytes(memoryview(p).cast("B")) for p in parts) + digest.digest()


# -- reading ------------------------------------------------------------------------------------
class _Fields:
    """Field checks of one file: every failure an :class:`hevr.IntegrityError` naming the field."""

    def __init__(self, where: str) -> None:
        self.where = where

    def fail(self, name: str, expected: str, got: Any) -> IntegrityError:
        text = repr(got)
        return IntegrityError(
            f"{self.where}: header field '{name}': expected {expected}, got "
            f"{text[:80] + '…' if len(text) > 80 else text}; no image is returned"
        )

    def integer(self, h: dict, name: str, lo: int, hi: int) -> int:
        v = h[name]
        if type(v) is not int or not lo <= v <= hi:
            raise self.fail(name, f"an integer in [{lo}, {hi}]", v)
        return v


def parse_packed(blob: bytes, where: str) -> dict:
    """The fields of the :class:`~hevr.rendering.packed.image.PackedImage` in the bytes of a packed
    frame file (``where`` names it in messages), checked in the module docstring's order:
    ``PackedImage(**fields)`` but for ``verification`` (None, or the keyword arguments of a
    :class:`~hevr.rendering.packed.verified.PackedVerification` read from a file) and ``stamp``
    ((stamp, what it authenticates, saved as) or None). :func:`hevr.load_image` builds them."""
    if not is_packed_frame(blob):
        raise CorruptStoreError(f"{where}: not a packed frame file (bad magic)")
    version = blob[len(MAGIC_PREFIX)] if len(blob) > len(MAGIC_PREFIX) else None
    if version != VERSION:
        raise CorruptStoreError(
            f"{where}: unsupported packed frame format version {version}; this hevr reads version {VERSION}"
        )
    if len(blob) < HEAD + DIGEST_BYTES:
        raise IntegrityError(
            f"{where}: truncated: {len(blob)} bytes, shorter than any packed frame file; no image is returned"
        )
    view = memoryview(blob)
    if hashlib.sha256(view[:-DIGEST_BYTES]).digest() != bytes(view[-DIGEST_BYTES:]):
        raise IntegrityError(
            f"{where}: checksum mismatch: the file was corrupted, truncated or altered after it was "
            "written; no image is returned"
        )
    (hl,) = LENGTH.unpack_from(blob, len(MAGIC))
    if hl > min(MAX_HEADER, len(blob) - HEAD - DIGEST_BYTES):
        raise IntegrityError(
            f"{where}: header length: expected at most "
            f"{min(MAX_HEADER, len(blob) - HEAD - DIGEST_BYTES)} bytes, got {hl}; no image is returned"
        )
    try:
        h = parse_json(bytes(view[HEAD : HEAD + hl]), where)
    except CorruptStoreError as exc:
        raise IntegrityError(f"{exc}; no image is returned") from None
    f = _Fields(where)
    if not isinstance(h, dict):
        raise f.fail("(header)", "a JSON object", type(h).__name__)
    missing, extra = sorted(FIELDS - set(h)), sorted(set(h) - FIELDS - OPTIONAL)
    if missing or extra:
        raise f.fail(
            missing[0] if missing else extra[0],
            f"exactly the fields {sorted(FIELDS)} (and a verified frame's {sorted(OPTIONAL)})",
            "nothing" if missing else "an unexpected field",
        )
    if h["format"] != FORMAT:
        raise f.fail("format", repr(FORMAT), h["format"])
    f.integer(h, "version", VERSION, VERSION)
    body = np.frombuffer(blob, np.uint8, count=len(blob) - HEAD - hl - DIGEST_BYTES, offset=HEAD + hl)
    stamp = read_stamp(h, hashlib.sha256(memoryview(blob)[HEAD + hl : HEAD + hl + body.size]).digest(), f.fail)
    meta, fm = _metadata(h, f)
    plan, span, camera = _plan(h, f, fm)
    width = int(fm.ciphertext_bytes)
    assert fm.scalar is not None and fm.packing is not None  # _metadata: a packed store's, or refused
    channel, k, exponent, offset = "scalar", 1, fm.scalar.exponent, fm.packing.offset
    if "channel" in h:  # a colour frame: the k components of the vector or gradient channel
        channel = h["channel"]
        if channel not in COLOUR_CHANNELS or getattr(fm, channel) is None or int(h["level"]):
            raise f.fail("channel", f"one of {list(COLOUR_CHANNELS)} that the store holds, at level 0", channel)
        k, exponent, offset = fm.components(channel), getattr(fm, channel).exponent, 0
        lo, hi = mantissa_range((0.0, 1.0), exponent)
        span = hi - lo
        try:
            plan.check_slots(span)
        except _BAD as exc:
            raise f.fail("channel", f"a channel whose sums fit the store's slots ({exc})", channel) from None
    counts = h["counts"]
    T = plan.n_tiles
    if not isinstance(counts, list) or len(counts) != k * T:
        per = f", for {k} components" if k > 1 else ""
        raise f.fail(
            "counts",
            f"a list of {k * T} integers (the frame plan's tiles{per})",
            f"a list of {len(counts)}" if isinstance(counts, list) else counts,
        )
    for i, c in enumerate(counts):
        t = i % T
        j0, j1, b0, b1 = plan.tile_bounds(t)
        if type(c) is not int or c != (j1 - j0) * (b1 - b0):
            raise f.fail(f"counts[{t}]", f"{(j1 - j0) * (b1 - b0)} (rows × blocks of the plan's tile {t})", c)
    if body.size != sum(counts) * width:
        what = "truncated" if body.size < sum(counts) * width else "too long"
        raise IntegrityError(
            f"{where}: {what}: expected {sum(counts) * width} record bytes (sum of counts × "
            f"{width}), got {body.size}; no image is returned"
        )
    tiles, pos = [], 0
    for c in counts:
        tiles.append(body[pos : pos + c * width].reshape(c, width))
        pos += c * width
    v = _verification(h, f, meta, int(h["level"]))
    if v is not None and channel != "scalar":
        v = dict(v, channel=channel, components=k)
    return {
        "plan": plan,
        "camera": camera,
        "fingerprint": fm.fingerprint,
        "n": int(fm.n),
        "exponent": exponent,
        "offset": offset,
        "span": span,
        "ciphertexts": tiles,
        "store_id": fm.store_id,
        "meta": meta,
        "level": int(h["level"]),
        "stamp": stamp,
        "verification": v,
        "channel": channel,
        "components": k,
    }


def _metadata(h: dict, f: _Fields) -> tuple[VolumeMetadata, VolumeMetadata]:
    """The store's metadata (its checksum, fields and key) and its level's."""
    try:
        meta = VolumeMetadata.from_dict(h["metadata"], where=f"{f.where}: metadata")
    except _BAD as exc:
        raise f.fail("metadata", f"a packed store's metadata ({exc})", "another document") from None
    try:
        n = int(meta.n)
        good_key = fingerprint_of(n) == meta.fingerprint and record_width(n) == meta.ciphertext_bytes
    except ValueError:
        good_key = False
    if not good_key:
        raise f.fail(
            "metadata", "a public key whose fingerprint and record width are those of its modulus n", "another key"
        )
    level = f.integer(h, "level", 0, min(MAX_LEVELS, len(meta.levels)))
    fm = meta.level_meta(level) if level else meta
    if fm.packing is None or fm.scalar is None:
        raise f.fail(
            "metadata", f"a packed store's metadata (level {level}: packed, the scalar channel)", "a per-voxel store's"
        )
    return meta, fm


def _plan(h: dict, f: _Fields, fm: VolumeMetadata) -> tuple[SlicePlan, int, Camera]:
    """The frame's plan, rebuilt from the header as ``hevr.render`` built it, the mantissa span
    and the camera."""
    if h["sampling"] not in ("nearest", "trilinear"):
        raise f.fail("sampling", "'nearest' or 'trilinear'", h["sampling"])
    wb = f.integer(h, "weight_bits", 0, MAX_WEIGHT_BITS)
    tile = f.integer(h, "tile", 1, MAX_TILE)
    try:
        cam = Camera.from_dict(h["camera"])
    except _BAD as exc:
        raise f.fail("camera", f"a camera (Camera.to_dict: {exc})", h["camera"]) from None
    if not cam.parallel:
        raise f.fail("camera", "a parallel camera (a packed frame's)", "a perspective camera")
    assert fm.scalar is not None and fm.packing is not None  # _metadata: a packed store's, or refused
    try:
        check_render_size(cam, fm.shape, fm.spacing, 1.0)  # the size limits, before anything per pixel
        plan = SlicePlan.build(cam, fm.shape, fm.spacing, fm.brick, fm.packing, h["sampling"], tile, wb)
        lo, hi = mantissa_range(fm.value_range, fm.scalar.exponent)
        plan.check_slots(hi - lo)
    except _BAD as exc:
        raise f.fail("camera", f"a view the store's packing serves ({exc})", "another") from None
    except MemoryError:  # a backstop: the plan's own size check comes first (check_plan_size)
        raise f.fail("metadata", "a store whose frame plan fits in memory", "one that does not") from None
    return plan, hi - lo, cam


def _verification(h: dict, f: _Fields, meta: VolumeMetadata, level: int) -> dict | None:
    """The record of a verified frame (or None): checked, never trusted before the stamp is."""
    if "verification" not in h:
        return None
    d = h["verification"]
    if not isinstance(d, dict) or set(d) != RECORD:
        raise f.fail("verification", f"an object with exactly {sorted(RECORD)}", d)
    n = int(meta.n)
    agg = d["aggregate"]
    if not (
        isinstance(agg, str)
        and agg.isascii()
        and agg.isdigit()
        and len(agg) <= 2 * len(str(n))
        and 0 < int(agg) < n * n
    ):
        raise f.fail("verification.aggregate", "a decimal string of a ciphertext in (0, n²)", agg)
    seed = d["seed"]
    if not (isinstance(seed, str) and len(seed) == 64 and all(c in "0123456789abcdef" for c in seed)):
        raise f.fail("verification.seed", "64 lower-case hex digits", seed)
    if not meta.tags:
        raise f.fail("verification", "no record (the store's metadata has no tags)", "a record")
    return {"aggregate": int(agg), "seed": bytes.fromhex(seed), "meta": meta, "level": level}
