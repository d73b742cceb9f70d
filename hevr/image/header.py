"""The ``.hevr`` file layout of :mod:`hevr.image` (version 3; version 2 is still read): the
header written (:func:`file_parts`) and the checks of a file's header (:func:`parse_file`).

A file is checked in this order, and nothing sized by a header field is allocated before that
field has been checked (errors come in milliseconds; memory stays a small multiple of the file
size): magic and version, the SHA-256 trailer over everything before it
(:class:`hevr.IntegrityError`), the header length, the header's JSON (limited number of
containers and strings, no duplicate keys, no integer of more than 40 digits), then every field
(:class:`hevr.CorruptStoreError`, ``"<file>: header field 'tile': expected an int >= 1, got 0"``)
and the size of the ciphertext body. The layout is in ``docs/image-format.md``.

The numeric rules (:func:`~hevr.image.checks.check_numbers`) and the ciphertext counts per
tile (:func:`~hevr.image.checks.check_image`) live in :mod:`hevr.image.checks`, shared with
an image in memory, which is checked before it is decrypted or saved (:class:`hevr.IntegrityError`).
"""

from __future__ import annotations

import base64
import hashlib
import json
import struct
from typing import Any, NoReturn

import numpy as np

from ..core.limits import integrity_bits
from ..core.magic import IMAGE_MAGIC_PREFIX
from ..crypto.paillier import fingerprint
from ..crypto.records import record_width
from ..errors import CorruptStoreError, IntegrityError
from .checks import (
    MAX_COMPONENTS,
    MAX_PIXELS,
    Fields,
    _clip,
    _is_int,
    _kind,
    _show,
    check_frame,
    check_image,
    check_numbers,
    check_shape,
    expected_counts,
    tile_hit_counts,
    tile_name,
)
from .stamp import STAMP_FIELDS, read_stamp, stamp_header
from .tiles import TileLayout

__all__ = [
    "DIGEST_BYTES",
    "FORMAT",
    "MAGIC",
    "MAGIC_PREFIX",
    "VERSION",
    "Fields",
    "check_image",
    "check_numbers",
    "expected_counts",
    "file_parts",
    "integrity_bits",
    "parse_file",
    "parse_json",
    "tile_hit_counts",
    "tile_name",
]

MAGIC_PREFIX = IMAGE_MAGIC_PREFIX
VERSION = 3
READS = (2, 3)  # version 2: server-finished images only (no finish/channel/components fields)
MAGIC = MAGIC_PREFIX + bytes([VERSION])
FORMAT = "hevr-encrypted-image"
DIGEST_BYTES = 32  # SHA-256 trailer
LENGTH = struct.Struct("<I")
HEAD = len(MAGIC) + LENGTH.size

MAX_N_DIGITS = 4300  # Python's default int/str conversion limit (about a 14 000-bit modulus)
MAX_INT_DIGITS = 40  # any JSON integer of the header (counts, shape, exponent, ...)
MAX_CONTAINERS = 16384  # '[' plus '{' in the header
MAX_QUOTES = 65536  # '"' in the header (two per string)
FIELDS_V2 = (
    "format",
    "version",
    "shape",
    "exponent",
    "offset",
    "bound",
    "fingerprint",
    "n",
    "width",
    "tile",
    "pack_bits",
    "per_pack",
    "counts",
    "hits",
    "info",
)
FIELDS = FIELDS_V2 + ("finish", "channel", "components")
SAMPLE_BYTES = 4  # a client-finished frame's body ends with H·W little-endian uint32 sample counts


# -- writing ------------------------------------------------------------------------------------
def _header(img: Any) -> dict:
    """The JSON header of an :class:`~hevr.image.EncryptedImage` (version 3)."""
    hits = None if img.hits is None else np.packbits(img.hits.ravel())
    return {
        "format": FORMAT,
        "version": VERSION,
        "shape": [int(x) for x in (img.shape[:2] if img.finish == "client" else img.shape)],
        "exponent": int(img.exponent),
        "offset": str(int(img.offset)),
        "bound": str(int(img.bound)),
        "fingerprint": img.fingerprint,
        "n": str(int(img.n)),
        "width": record_width(int(img.n)),
        "tile": int(img.tile),
        "pack_bits": int(img.pack_bits),
        "per_pack": int(img.per_pack),
        "counts": [len(c) for c in img.ciphertexts],
        "hits": None if hits is None else base64.b64encode(hits.tobytes()).decode(),
        "info": img.info,
        "finish": img.finish,
        "channel": img.channel,
        "components": None if img.components is None else int(img.components),
        **({"verification": img.verification.to_dict()} if img.verification is not None else {}),
    }


def file_parts(img: Any, private_key: Any = None, saved_as: str = "") -> list:
    """The file's bytes before its SHA-256 trailer: magic, header length, header, records (and a
    client-finished frame's sample counts). The image is not checked here: its writers do that
    first (:func:`~hevr.image.checks.check_image`). A verified image carries the key holder's
    stamp (:mod:`hevr.image.stamp`): made with ``private_key`` (whose holder checked it), else the
    one it was read with, if any; the stamp binds the file's name ``saved_as`` too (a stamped frame
    put in another frame's place is refused: :meth:`hevr.EncryptedImage.decrypt`)."""
    header = _header(img)
    body = [np.ascontiguousarray(c, dtype=np.uint8).reshape(-1) for c in img.ciphertexts]
    if img.finish == "client":  # the public sample counts the client divides by
        body.append(np.ascontiguousarray(img.samples, dtype="<u4").reshape(-1))
    stamp_header(header, body, img, private_key, saved_as)
    head = json.dumps(header, separators=(",", ":")).encode()
    return [MAGIC, LENGTH.pack(len(head)), head, *body]


# -- reading ------------------------------------------------------------------------------------
def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set[str] = set()
        dup = next(k for k, _ in pairs if k in seen or _seen(seen, k))
        raise ValueError(f"duplicate key {_show(dup)}")
    return out


def _seen(seen: set[str], key: str) -> bool:
    """Add ``key`` to ``seen``; False (so that a generator's condition goes on to the next key)."""
    seen.add(key)
    return False


def _small_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {len(text)} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def parse_json(raw: bytes, where: str) -> Any:
    def bad(why: str) -> NoReturn:
        raise CorruptStoreError(f"{where}: header: expected a JSON object, got {why}")

    containers = raw.count(b"[") + raw.count(b"{")
    if containers > MAX_CONTAINERS:
        bad(f"{containers} '[' and '{{' (at most {MAX_CONTAINERS})")
    quotes = raw.count(b'"')
    if quotes > MAX_QUOTES:
        bad(f"{quotes} '\"' (at most {MAX_QUOTES})")
    try:
        return json.loads(raw.decode("utf-8"), object_pairs_hook=_no_duplicates, parse_int=_small_int)
    except RecursionError:
        bad("JSON nested too deeply")
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, the hooks'
        bad(f"invalid JSON ({_clip(str(exc))})")


def parse_file(blob: bytes, where: str) -> tuple[dict, np.ndarray]:
    """Check a whole ``.hevr`` file; return its checked header values and its ciphertext body.

    The values: ``shape`` (tuple), ``n``, ``offset``, ``bound`` (ints), ``exponent``, ``tile``,
    ``pack_bits``, ``per_pack``, ``width`` (ints), ``fingerprint``, ``counts`` (list of int),
    ``hits`` (bool (H, W) array or None), ``info`` (dict). The body is a uint8 view of ``blob``.
    """
    if len(blob) < len(MAGIC) or not blob.startswith(MAGIC_PREFIX):
        raise CorruptStoreError(f"{where}: not an hevr encrypted image (bad magic)")
    version = blob[len(MAGIC_PREFIX)]
    if version == 1:
        raise CorruptStoreError(
            f"{where}: image format version 1 is no longer read (it has no checksum and "
            f"no value bound to check decryption against); render the image again"
        )
    if version not in READS:
        raise CorruptStoreError(
            f"{where}: unsupported image format version {version}; this hevr reads versions {READS[0]} and {READS[-1]}"
        )
    if len(blob) < HEAD + DIGEST_BYTES:
        raise CorruptStoreError(f"{where}: truncated: {len(blob)} bytes, shorter than any version-{version} image")
    view = memoryview(blob)
    if hashlib.sha256(view[:-DIGEST_BYTES]).digest() != bytes(view[-DIGEST_BYTES:]):
        raise IntegrityError(
            f"{where}: checksum mismatch: the file was corrupted, truncated or altered after "
            f"it was written; no image is returned"
        )
    (hl,) = LENGTH.unpack_from(blob, len(MAGIC))
    if hl > len(blob) - HEAD - DIGEST_BYTES:
        raise CorruptStoreError(
            f"{where}: header length: expected at most {len(blob) - HEAD - DIGEST_BYTES} "
            f"bytes (the file's size), got {hl}"
        )
    h = parse_json(bytes(view[HEAD : HEAD + hl]), where)
    if not isinstance(h, dict):
        raise CorruptStoreError(f"{where}: header: expected a JSON object, got a JSON {_kind(h)}")
    ctx = Fields(where, CorruptStoreError, "header field")
    stamp = read_stamp(h, hashlib.sha256(view[HEAD + hl : len(blob) - DIGEST_BYTES]).digest(), ctx.fail)
    out = _check_header(h, ctx, version)
    body = np.frombuffer(blob, dtype=np.uint8, count=len(blob) - HEAD - hl - DIGEST_BYTES, offset=HEAD + hl)
    size = sum(out["counts"]) * out["width"]
    H, W = out["shape"][:2]
    extra = H * W * SAMPLE_BYTES if out["finish"] == "client" else 0
    if body.size != size + extra:
        what = "truncated" if body.size < size + extra else "too long"
        more = f" and {extra} bytes of sample counts" if extra else ""
        raise CorruptStoreError(
            f"{where}: {what}: expected {size} ciphertext bytes (sum of counts × width){more}, got {body.size}"
        )
    out["samples"] = None
    if extra:
        samples = body[size:].view("<u4").reshape(H, W).astype(np.int64)
        if not np.array_equal(samples > 0, out["hits"] if out["hits"] is not None else np.ones((H, W), bool)):
            ctx.fail("hits", "the pixels whose sample count (after the records) is > 0", raw="another mask")
        out["samples"] = samples
        body = body[:size]
    out["stamp"] = stamp
    return out, body


def _check_header(h: dict, ctx: Fields, version: int = VERSION) -> dict:
    if h.get("format") != FORMAT:
        ctx.fail("format", repr(FORMAT), h.get("format"))
    if not _is_int(h.get("version")) or h["version"] != version:
        ctx.fail("version", str(version), h.get("version"))
    fields = FIELDS if version >= 3 else FIELDS_V2
    for name in fields:
        if name not in h:
            ctx.fail(name, "the field", raw="nothing")
    extra = sorted(set(h) - set(fields) - ({"verification", *STAMP_FIELDS} if version >= 3 else set()))
    if extra:
        raise CorruptStoreError(f"{ctx.where}: header: unexpected field {_show(extra[0])}")
    shape = check_shape(ctx, h["shape"])
    n = ctx.decimal("n", h["n"], MAX_N_DIGITS)
    width = record_width(n)
    if not _is_int(h["width"]) or h["width"] != width:
        ctx.fail("width", f"{width} (the record width of n: ceil(2·bits(n)/8) bytes)", h["width"])
    fp = h["fingerprint"]
    if fp != fingerprint(n):
        ctx.fail("fingerprint", "the SHA-256 of n (64 hex digits)", fp)
    bound = ctx.decimal("bound", h["bound"], MAX_N_DIGITS)
    offset = ctx.decimal("offset", h["offset"], MAX_N_DIGITS)
    check_numbers(
        ctx,
        n=n,
        exponent=h["exponent"],
        bound=bound,
        offset=offset,
        tile=h["tile"],
        pack_bits=h["pack_bits"],
        per_pack=h["per_pack"],
    )
    H, W = shape[:2]
    tile, per_pack = h["tile"], h["per_pack"]
    hits = _check_hits(ctx, h["hits"], H, W)
    h["hits"] = None  # drop the base64 text early
    layout = TileLayout(W, H, tile)
    counts = h["counts"]
    if not isinstance(counts, list) or len(counts) != layout.n_tiles:
        ctx.fail(
            "counts",
            f"a list of {layout.n_tiles} ints (one per tile)",
            raw=f"a list of {len(counts)}" if isinstance(counts, list) else _kind(counts),
        )
    top = MAX_COMPONENTS * MAX_PIXELS  # no tile needs more ciphertexts
    for t, c in enumerate(counts):
        if not _is_int(c) or not 0 <= c <= top:
            ctx.fail(
                f"counts[{t}]",
                "an int >= 0 (ciphertexts of the tile)",
                raw=f"{_show(c)}" + ("" if _is_int(c) else f" ({_kind(c)})"),
            )
    finish, channel, components = (
        (h["finish"], h["channel"], h["components"]) if version >= 3 else ("server", None, None)
    )
    per_pixel = check_frame(ctx, finish, channel, components, shape)
    if finish == "client" and len(shape) != 2:
        ctx.fail("shape", "[H, W] for a frame finished on the client (its colouring is not in the file)", shape)
    if finish == "client" and hits is None:
        ctx.fail("hits", "the mask of the pixels with samples (a client-finished frame)", raw="null")
    want = expected_counts(tile_hit_counts(hits, (H, W), tile), per_pixel, per_pack)
    bad = np.flatnonzero(np.array(counts, dtype=np.int32) != want)
    if bad.size:
        t = int(bad[0])
        ctx.fail(
            f"counts[{t}]",
            f"{int(want[t])} (the hit pixels of {tile_name(layout, t)} × channels / per_pack, rounded up)",
            counts[t],
        )
    if not isinstance(h["info"], dict):
        ctx.fail("info", "a JSON object", raw=_kind(h["info"]))
    return {
        "shape": shape,
        "n": n,
        "width": width,
        "fingerprint": fp,
        "bound": bound,
        "offset": offset,
        "exponent": int(h["exponent"]),
        "tile": int(tile),
        "pack_bits": int(h["pack_bits"]),
        "per_pack": int(per_pack),
        "counts": counts,
        "hits": hits,
        "info": h["info"],
        "finish": finish,
        "channel": channel,
        "components": components,
        "verification": h.get("verification"),
    }


def _check_hits(ctx: Fields, text: Any, H: int, W: int) -> np.ndarray | None:
    """The (H, W) mask from base64 of np.packbits; its length is checked before decoding."""
    if text is None:
        return None
    nbytes = -(-H * W // 8)
    length = 4 * -(-nbytes // 3)
    if not isinstance(text, str):
        ctx.fail("hits", f"a base64 string of {length} characters or null", raw=f"{_show(text)} ({_kind(text)})")
    if len(text) != length:
        ctx.fail(
            "hits",
            f"a base64 string of {length} characters (ceil(H·W/8) = {nbytes} bytes)",
            raw=f"{len(text)} characters",
        )
    try:
        packed = base64.b64decode(text, validate=True)
    except ValueError:
        ctx.fail("hits", "base64 (A-Z, a-z, 0-9, +, /, = padding)", raw="other characters")
    if len(packed) != nbytes:
        ctx.fail("hits", f"{nbytes} bytes once decoded", raw=f"{len(packed)}")
    spare = nbytes * 8 - H * W
    if spare and packed[-1] & ((1 << spare) - 1):
        ctx.fail("hits", f"zero padding bits after the {H * W} pixels", raw="set bits")
    bits = np.unpackbits(np.frombuffer(packed, np.uint8), count=H * W)
    del packed
    return bits.view(bool).reshape(H, W)
