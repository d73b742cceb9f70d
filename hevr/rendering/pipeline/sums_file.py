"""The ``.hevrsums`` file: a view's merged encrypted ray sums, written beside a render and read back.

``hevr.render(..., keep_sums=PATH)`` (``hevr render --keep-sums``) writes the sums with
:func:`save_sums`; :func:`hevr.load_sums` reads them (:func:`read_sums` checks the bytes) and
:func:`hevr.recolour` finishes them with another density or transfer function
(:mod:`hevr.rendering.pipeline.sums`).


File layout (version 1; little-endian; everything public — ciphertexts and render geometry,
safe to keep on the server):

* 9 bytes: ``HEVRSUMS`` and the version byte ``0x01``;
* 4 bytes: header length L (uint32); L bytes of JSON header: ``format``, ``version``,
  ``n`` (decimal string), ``fingerprint``, ``volume`` (the store's public metadata, as in its
  ``hevr`` attribute, checksum included), ``store`` (its path when rendered, for information),
  ``camera`` (:meth:`hevr.Camera.to_dict`, or a slice's :meth:`hevr.Plane.to_dict`, told apart by
  its ``kind: "plane"``), ``sampling``, ``step``, ``weight_digits``,
  ``channel`` (``"scalar"``, ``"vector"`` or ``"gradient"``), ``tile``, ``width`` (bytes per ciphertext),
  ``components`` (K) and ``tiles``: one ``[tile, R]`` per image tile, R rays with sums, or -1
  for a tile no brick touches;
* per tile with R >= 0: R int64 global pixel indices (strictly increasing, inside the tile),
  then R·K·width bytes of ciphertext records;
* 32 bytes: SHA-256 of everything before.

Loading checks the checksum first (:class:`hevr.IntegrityError`), then every header field and
the body's size before anything sized by them is allocated (:class:`hevr.CorruptStoreError`),
then every ciphertext's range (0 < c < n²).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import struct
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...backends import get_backend
from ...core.files import require_file
from ...core.limits import MAX_IMAGE_PIXELS
from ...core.magic import SUMS_MAGIC_PREFIX
from ...core.validate import check_bool, check_step
from ...crypto.paillier import fingerprint as fingerprint_of
from ...crypto.records import record_width
from ...errors import CorruptStoreError, ExistingFileError, HevrError, IntegrityError, ParameterError
from ...image.checks import Fields
from ...image.header import MAX_N_DIGITS, parse_json
from ...image.tiles import TileLayout
from ...store.metadata import VolumeMetadata
from ...store.paths import check_storage_options, output_location, write_output
from ...volume.pyramid import MAX_LEVELS
from ..geometry.camera import Camera
from ..geometry.plane import Plane, view_from_dict

if TYPE_CHECKING:
    from .sums import RaySums

log = logging.getLogger(__name__)

__all__ = ["MAGIC", "check_sums_path", "read_sums", "save_sums"]


MAGIC = SUMS_MAGIC_PREFIX + bytes([1])
FORMAT = "hevr-ray-sums"
VERSION = 1
LENGTH = struct.Struct("<I")
DIGEST = 32
FIELDS = (
    "format",
    "version",
    "n",
    "fingerprint",
    "volume",
    "store",
    "level",
    "camera",
    "sampling",
    "step",
    "weight_digits",
    "channel",
    "tile",
    "width",
    "components",
    "tiles",
)


def save_sums(
    path: str | os.PathLike[str],
    sums: RaySums,
    *,
    meta: VolumeMetadata,
    camera: Camera | Plane,
    sampling: str,
    step: float,
    weight_digits: int,
    channel: str,
    tile: int,
    store: str = "",
    level: int = 0,
    storage_options: dict | None = None,
    overwrite: bool = False,
    name: str = "path",
) -> int:
    """Write ``sums`` (gathered from the workers if needed) as a ``.hevrsums`` file. Returns the
    file's size in bytes.

    As :meth:`hevr.EncryptedImage.save`: atomic (a temporary sibling linked into place, or
    renamed over ``path`` with ``overwrite=True``; an fsspec URL with ``storage_options``: one
    request), never over an existing file unless ``overwrite=True``
    (:class:`hevr.ExistingFileError` naming ``name``), a failed write a
    :class:`hevr.FileSystemError` that leaves nothing behind."""
    overwrite = check_bool("overwrite", overwrite)
    where = output_location(path, name)
    values = sums.values()
    n = int(meta.n)
    width = record_width(n)
    K = meta.components(channel)
    head = {
        "format": FORMAT,
        "version": VERSION,
        "n": str(n),
        "fingerprint": meta.fingerprint,
        "volume": meta.to_dict(),
        "store": str(store),
        "level": int(level),
        "camera": camera.to_dict(),
        "sampling": sampling,
        "step": float(step),
        "weight_digits": int(weight_digits),
        "channel": channel,
        "tile": int(tile),
        "width": width,
        "components": K,
        "tiles": [[int(t), -1 if v is None else int(v[0].size)] for t, v in sorted(values.items())],
    }
    blob = json.dumps(head, separators=(",", ":")).encode()
    parts: list[Any] = [MAGIC, LENGTH.pack(len(blob)), blob]
    for _, v in sorted(values.items()):
        if v is not None:
            parts += [
                np.ascontiguousarray(v[0], dtype="<i8").reshape(-1),
                np.ascontiguousarray(v[1], dtype=np.uint8).reshape(-1),
            ]
    size = write_output(
        where,
        parts,
        check_storage_options(storage_options),
        overwrite=overwrite,
        name=name,
        doing="writing the ray sums",
    )
    log.info("ray sums of %d tiles written to %s (%d bytes)", len(values), where, size)
    return size


def read_sums(blob: bytes, where: str) -> dict[str, Any]:
    """The checked fields of a :class:`~hevr.rendering.pipeline.sums.SavedSums` in the bytes of a
    ``.hevrsums`` file (``where`` names it in messages)."""
    if not blob.startswith(MAGIC[:-1]):
        raise CorruptStoreError(f"{where}: not an hevr ray-sums file (bad magic)")
    if len(blob) >= len(MAGIC) and blob[len(MAGIC) - 1] != VERSION:
        raise CorruptStoreError(f"{where}: expected ray-sums format version {VERSION}, got {blob[len(MAGIC) - 1]}")
    if len(blob) < len(MAGIC) + LENGTH.size + DIGEST:
        raise CorruptStoreError(f"{where}: truncated: {len(blob)} bytes, shorter than any ray-sums file")
    view = memoryview(blob)
    if hashlib.sha256(view[:-DIGEST]).digest() != bytes(view[-DIGEST:]):
        raise IntegrityError(
            f"{where}: checksum mismatch: the file was corrupted, truncated or altered after it "
            "was written; no sums are returned"
        )
    (hl,) = LENGTH.unpack_from(blob, len(MAGIC))
    start = len(MAGIC) + LENGTH.size
    if hl > len(blob) - start - DIGEST:
        raise CorruptStoreError(f"{where}: header length: expected at most {len(blob) - start - DIGEST}, got {hl}")
    h = parse_json(bytes(view[start : start + hl]), where)
    ctx = Fields(where, CorruptStoreError, "header field")
    if not isinstance(h, dict):
        ctx.fail("header", "a JSON object", h)
    for name in FIELDS:
        if name not in h:
            ctx.fail(name, "the field", raw="nothing")
    extra = sorted(set(h) - set(FIELDS))
    if extra:  # as the .hevr header: a field this version does not write is not silently ignored
        shown = repr(extra[0]) if len(extra[0]) <= 40 else repr(extra[0][:30]) + f"… ({len(extra[0])} chars)"
        raise CorruptStoreError(
            f"{where}: header: unexpected field {shown} (a ray-sums header of version "
            f"{VERSION} holds exactly {', '.join(FIELDS)})"
        )
    if h["format"] != FORMAT:
        ctx.fail("format", repr(FORMAT), h["format"])
    ctx.integer("version", h["version"], VERSION, VERSION)
    n = ctx.decimal("n", h["n"], MAX_N_DIGITS)
    if h["fingerprint"] != fingerprint_of(n):
        ctx.fail("fingerprint", "the SHA-256 fingerprint of n", h["fingerprint"])
    meta = VolumeMetadata.from_dict(h["volume"], where=f"{where}: header field 'volume'")
    if int(meta.n) != n:
        ctx.fail("volume", "the metadata of a volume under the same key", raw="another key's")
    try:
        camera = view_from_dict(h["camera"])  # a Camera, or a Plane (kind "plane": hevr.render_slice)
    except HevrError as exc:
        raise CorruptStoreError(f"{where}: header field 'camera': {exc}") from None
    if camera.width * camera.height > MAX_IMAGE_PIXELS:  # before anything is sized by the image
        ctx.fail("camera", f"an image of at most {MAX_IMAGE_PIXELS} pixels", raw=f"{camera.width}x{camera.height}")
    if h["sampling"] not in ("nearest", "trilinear"):
        ctx.fail("sampling", "'nearest' or 'trilinear'", h["sampling"])
    try:
        step = check_step(h["step"])  # the render's own rule
    except (ParameterError, OverflowError):
        ctx.fail("step", "a positive finite number", h["step"])
    channel = h["channel"]
    if channel not in meta.channel_names:
        ctx.fail("channel", f"one of the volume's channels {list(meta.channel_names)}", channel)
    K = meta.components(channel)
    ctx.integer("components", h["components"], K, K)
    width = ctx.integer("width", h["width"], record_width(n), record_width(n))
    tile = ctx.integer("tile", h["tile"], 1, 4096)
    layout = TileLayout(camera.width, camera.height, tile)
    tiles = _read_tiles(ctx, h["tiles"], layout, view[start + hl : -DIGEST], K, width, n)
    nearest = h["sampling"] == "nearest"
    digits = ctx.integer("weight_digits", h["weight_digits"], 0, 0 if nearest else 9)  # nearest weights are counts
    return dict(
        meta=meta,
        camera=camera,
        sampling=h["sampling"],
        step=float(step),
        weight_digits=digits,
        channel=channel,
        tile=tile,
        tiles=tiles,
        store=str(h["store"]),
        level=ctx.integer("level", h["level"], 0, MAX_LEVELS),
        path=where,
    )


def check_sums_path(path: Any, name: str = "keep_sums", *, overwrite: bool = False) -> Path | str:
    """Where a ``.hevrsums`` file may be written: a non-empty path, not a folder, in an existing
    folder, with no file there unless ``overwrite`` (:class:`hevr.ExistingFileError`) —
    checked before a render runs, so a bad path costs no map work (:func:`save_sums` refuses
    an existing file again, atomically, when it writes)."""
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ParameterError(f"{name}: expected a file path, got {path!r}")
    where = output_location(path, name)
    if not isinstance(where, Path):
        return where  # an object: written in one request after the render (save_sums)
    p = where
    if p.is_dir():
        raise ParameterError(f"{name}: expected a file path, got a folder ({p})")
    require_file(p.parent if str(p.parent) else Path("."), name, "an existing folder for the file", directory=True)
    if not overwrite and (p.exists() or p.is_symlink()):
        raise ExistingFileError(name, p)
    return p


def _read_tiles(ctx: Fields, listed: Any, layout: TileLayout, body: memoryview, K: int, width: int, n: int) -> dict:
    """Every tile's (rays, records) from the body, sizes checked before anything is allocated."""
    if not isinstance(listed, list) or len(listed) != layout.n_tiles:
        ctx.fail(
            "tiles",
            f"a list of {layout.n_tiles} [tile, rays] pairs",
            raw=f"{type(listed).__name__} of {len(listed) if isinstance(listed, list) else '?'}",
        )
    counts = []
    for i, item in enumerate(listed):
        if not (isinstance(item, list) and len(item) == 2):
            ctx.fail(f"tiles[{i}]", "a [tile, rays] pair", item)
        ctx.integer(f"tiles[{i}][0]", item[0], i, i)
        r0, r1, c0, c1 = layout.bounds(i)
        counts.append(ctx.integer(f"tiles[{i}][1]", item[1], -1, (r1 - r0) * (c1 - c0)))
    per_ray = 8 + K * width
    need = sum(max(c, 0) for c in counts) * per_ray
    if len(body) != need:
        raise CorruptStoreError(
            f"{ctx.where}: {'truncated' if len(body) < need else 'too long'}: expected {need} "
            f"bytes of rays and records, got {len(body)}"
        )
    be = get_backend("cpu")
    n2 = n * n
    out: dict = {}
    pos = 0
    for t, R in enumerate(counts):
        if R < 0:
            out[t] = None
            continue
        rays = np.frombuffer(body, dtype="<i8", count=R, offset=pos).astype(np.int64)
        recs = np.frombuffer(body, dtype=np.uint8, count=R * K * width, offset=pos + 8 * R).reshape(R, K, width)
        pos += R * per_ray
        if R and (np.any(np.diff(rays) <= 0) or not np.isin(rays, layout.pixels(t)).all()):
            raise CorruptStoreError(
                f"{ctx.where}: tile {t}: expected strictly increasing pixel indices inside the tile, got others"
            )
        bad = be.first_out_of_range(be.from_bytes(recs.reshape(-1, width)), n2) if R else None
        if bad is not None:
            raise CorruptStoreError(f"{ctx.where}: tile {t}: ciphertext {bad} is not in (0, n²)")
        out[t] = (rays, recs.copy())
    return out
