"""Encrypted ray sums that outlive a render: the in-memory cache entry, the ``.hevrsums`` file,
and re-colouring from either.

The map and merge steps of a render produce, per image tile, the merged encrypted ray sums of
every stored component (scalar: one per ray; vector: k per ray). Everything after them — the
combination matrix of an emphasis density or a transfer function, Eq. 1's normalisation, the
offset and packing (:mod:`hevr.rendering.pipeline.finishing`) — depends only on these sums and public
numbers. So another density or transfer function on the same view needs no map step: the
sums are kept in memory (:class:`RaySums`, the render cache) or in a file
(``hevr.render(..., keep_sums=PATH)``, ``hevr render --keep-sums``), and :func:`recolour`
redoes only the finishing. The result is bit for bit the image a full render with the new
parameters gives.

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
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...backends import get_backend, resolve_backend_name
from ...colour import Colouring
from ...core.files import read_regular, require_file
from ...core.limits import MAX_IMAGE_PIXELS
from ...core.magic import SUMS_MAGIC_PREFIX
from ...core.validate import check_bool, check_choice, check_int, check_step
from ...crypto.paillier import fingerprint as fingerprint_of
from ...crypto.records import record_width
from ...errors import (
    CorruptStoreError,
    ExistingFileError,
    HevrError,
    IntegrityError,
    MissingFileError,
    ParameterError,
)
from ...image.checks import FINISHES, Fields
from ...image.encrypted import EncryptedImage
from ...image.header import MAX_N_DIGITS, parse_json
from ...image.tiles import TileLayout
from ...runtime.scheduler import active_client
from ...runtime.scheduler import compute as run_tasks
from ...store.metadata import VolumeMetadata
from ...store.paths import (
    check_storage_options,
    is_local,
    normalise,
    output_location,
    read_bytes,
    write_output,
)
from ...volume.pyramid import MAX_LEVELS
from ..geometry.camera import Camera
from ..geometry.plane import Plane, view_from_dict
from ..geometry.rays import cast_rays
from ..planning.modes import RenderSpec, combination_matrix, make_spec
from ..planning.planner import RenderPlan, check_render_size, plan_render
from .graph import BlockSums, FinishGraph, block_sums

log = logging.getLogger(__name__)

__all__ = ["RaySums", "SavedSums", "check_sums_path", "image_fields", "load_sums", "recolour", "save_sums"]

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


@dataclass
class RaySums:
    """Merged encrypted per-component ray sums of one view, per tile (reusable).

    On a distributed client ``tiles`` holds futures: the sums stay on the workers that
    merged them, and re-colouring runs its finishing tasks there (no sums cross the
    network); on a single machine it holds the values. ``packed`` keeps, per client-finished
    plan, the finishing units' outputs: the packed sums are the same for every colouring, so
    another density or transfer function on this view needs no task at all.
    """

    key: tuple
    tiles: dict  # tile id -> (rays, records (R, C, W)), a future of it, or None
    map_tasks: int
    client: Any = None
    packed: dict = field(default_factory=dict)  # client-finished RenderPlan -> its units' (P, W) outputs
    backend: str = "cpu"  # the backend that computed them

    def usable(self, client: Any) -> bool:
        """Whether these sums can serve a render on ``client`` (futures are bound to theirs)."""
        return client is self.client and (client is None or client.status == "running")

    def values(self) -> dict:
        """Tile id -> ``(rays, records)`` or None, gathered from the workers if they hold them
        (a tile's future, or the future of the reduce block holding it: :class:`BlockSums`)."""
        live = {t: v for t, v in self.tiles.items() if v is not None}
        if self.client is not None and live:
            futures = {t: v.block if isinstance(v, BlockSums) else v for t, v in live.items()}
            unique = list({f.key: f for f in futures.values()}.values())
            got = dict(zip((f.key for f in unique), self.client.gather(unique)))
            live = {
                t: block_sums(got[futures[t].key], v.tile) if isinstance(v, BlockSums) else got[futures[t].key]
                for t, v in live.items()
            }
        return {t: live.get(t) for t in self.tiles}


@dataclass(frozen=True)
class SavedSums:
    """The ray sums of one view as read from a ``.hevrsums`` file, checked.

    ``tiles`` maps every tile id to ``(rays (R,) int64, records (R, K, width) uint8)``, or to
    None for a tile no brick touches.
    """

    meta: VolumeMetadata
    camera: Camera | Plane
    sampling: str
    step: float
    weight_digits: int
    channel: str
    tile: int
    tiles: dict
    store: str
    level: int
    path: str


def image_fields(
    spec: RenderSpec,
    plan: RenderPlan,
    camera: Camera,
    n_samples: np.ndarray,
    meta: VolumeMetadata,
    tile: int,
    level: int = 0,
) -> dict:
    """Everything of an :class:`EncryptedImage` but its ciphertexts and stats (render and recolour).

    A client-finished plan (``plan.finish == "client"``) gives fields without the mode, the density
    and the nodes (they stay with the caller: :func:`with_colouring`), the pixel grid (H, W) as the
    shape, and the public sample counts the client divides by."""
    H, W = camera.height, camera.width
    client = plan.finish == "client"
    colouring = (
        {"channel": plan.channel}
        if client
        else {
            "mode": spec.mode,
            "density": spec.density,
            "nodes": [[d, list(c)] for d, c in spec.nodes] if spec.nodes else None,
        }
    )
    counts = np.asarray(n_samples).reshape(H, W)
    return dict(
        shape=(H, W) if client else spec.image_shape(H, W),
        exponent=plan.exponent,
        offset=plan.offset,
        fingerprint=meta.fingerprint,
        n=int(meta.n),
        tile=tile,
        pack_bits=plan.pack_bits,
        per_pack=plan.per_pack,
        hits=counts > 0,
        bound=plan.bound,
        finish=plan.finish,
        channel=plan.channel,
        components=plan.channels_out,
        samples=counts.astype(np.int64) if client else None,
        info={
            "sampling": spec.sampling,
            "step": spec.step,
            **colouring,
            "store": meta.store_id,
            "tags": bool(meta.tags),
            "camera": camera.to_dict(),
            "plan": plan.to_dict(),
            "finish": plan.finish,
            **({"gradient": True} if spec.gradient else {}),
            **({"level": level} if level else {}),
        },
    )  # a level's camera is in the level's frame


def with_colouring(fields: dict, spec: RenderSpec) -> dict:
    """The fields of the image returned in this process: a client-finished one gets the request's
    :class:`~hevr.colour.Colouring` and the shape it colours to ((H, W, 3) for a transfer
    function); neither is ever in a task, a file or a log."""
    if fields["finish"] != "client":
        return dict(fields, colouring=None)
    return dict(fields, colouring=Colouring.of(spec), shape=spec.image_shape(*fields["shape"][:2]))


def save_sums(
    path: str | os.PathLike,
    sums: RaySums,
    *,
    meta: VolumeMetadata,
    camera: Camera,
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


def load_sums(path: str | os.PathLike, *, storage_options: dict | None = None) -> SavedSums:
    """Read and check a ``.hevrsums`` file (module docstring: checksum, header, sizes, ranges);
    ``path`` may be an fsspec URL, read with ``storage_options``."""
    what = "a ray-sums file (hevr.render(..., keep_sums=PATH))"
    path = normalise(path) if "://" in str(path) else path
    if not is_local(str(path)):
        where = str(path)
        try:
            blob = read_bytes(where, check_storage_options(storage_options))
        except FileNotFoundError:
            raise MissingFileError("sums", what, where) from None
        return _parse(blob, where)
    if Path(path).is_dir():
        raise ParameterError(
            f"sums: expected a ray-sums file (hevr.render(..., keep_sums=PATH)), got a folder ({path})"
        )
    # never blocks: a FIFO or a device is a NotRegularFileError before a byte is read
    return _parse(read_regular(path, "sums", what), str(path))


def _parse(blob: bytes, where: str) -> SavedSums:
    """The checked sums in the bytes of a ``.hevrsums`` file (``where`` names it in messages)."""
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
    return SavedSums(
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


def recolour(
    sums: SavedSums | str | os.PathLike,
    mode: str = "tf",
    density: float | None = None,
    nodes: Any = None,
    *,
    precision: int = 4,
    comb_digits: int = 4,
    pack: bool = True,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    gradient: bool = False,
    finish: str = "client",
) -> EncryptedImage:
    """Finish saved ray sums with another density or transfer function: only the per-pixel step.

    Parameters
    ----------
    sums : SavedSums or path
        From :func:`load_sums`, or the path of a ``.hevrsums`` file.
    mode, density, nodes, precision, comb_digits, pack
        As for :func:`hevr.render`; the camera, sampling, step and weight digits are the sums'.
        ``emphasize`` and ``tf`` need sums of the vector channel, ``xray`` of the scalar one.
    client, progress, backend
        As for :func:`hevr.render`.
    gradient : bool
        ``emphasize`` / ``tf`` of sums of the gradient channel (a render with ``gradient=True``);
        sums of the vector channel need ``gradient=False``, and the other way round.
    finish : {"client", "server"}
        As for :func:`hevr.render`: ``"client"`` packs the saved sums for colouring at
        decryption (the density / nodes stay here); ``"server"`` finishes them on the workers.

    Returns
    -------
    EncryptedImage
        Bit for bit the image ``hevr.render`` gives for the same view and parameters.
    """
    if not isinstance(sums, SavedSums):
        sums = load_sums(sums)
    t0 = time.perf_counter()
    meta, camera = sums.meta, sums.camera
    spec = make_spec(
        mode,
        sums.sampling,
        sums.step,
        density,
        nodes,
        meta.vector.dims if meta.vector else None,
        meta.scalar is not None,
        gradient,
        meta.gradient is not None,
    )
    if spec.channel != sums.channel and {spec.channel, sums.channel} == {"vector", "gradient"}:
        raise ParameterError(
            f"gradient: expected sums of the {spec.channel} channel for gradient={spec.gradient}, got "
            f"the {sums.channel} channel's (rendered with gradient={not spec.gradient}; {sums.path}); "
            f"recolour them with gradient={not spec.gradient}"
        )
    if spec.channel != sums.channel:
        need = "an X-ray render" if spec.channel == "scalar" else "a render in mode 'emphasize' or 'tf'"
        raise ParameterError(
            f"sums: expected the {spec.channel} channel's sums ({need}) for mode {spec.mode!r}, "
            f"got the {sums.channel} channel's ({sums.path})"
        )
    precision = check_int("precision", precision, 0, 30)
    comb_digits = check_int("comb_digits", comb_digits, 1, 12)
    check_choice("finish", finish, FINISHES)
    backend = resolve_backend_name(backend, int(meta.n).bit_length(), client=active_client(client))
    checked = check_render_size(camera, meta.shape, meta.spacing, spec.step)
    rays = checked if checked is not None else cast_rays(camera, meta.shape, meta.spacing, spec.step)
    comb = combination_matrix(spec, meta.vector.dims) if spec.needs_vector and finish == "server" else None
    plan = plan_render(
        n=int(meta.n),
        spec=spec,
        meta=meta,
        n_samples=rays.n_samples,
        digits=sums.weight_digits if spec.sampling == "trilinear" else 0,
        precision=precision,
        comb_digits=comb_digits,
        pack=pack,
        combination=comb,
        finish=finish,
    )
    if plan.weight_digits != sums.weight_digits:  # the planner keeps the digits it is given; a guard
        raise CorruptStoreError(
            f"{sums.path}: expected weights of {plan.weight_digits} digits, got {sums.weight_digits}"
        )
    layout = TileLayout(camera.width, camera.height, sums.tile)
    finish = FinishGraph.plan_units(plan, layout, rays.n_samples, int(meta.n), backend)
    fin = finish.tasks(sums.tiles)
    packed = finish.assemble(run_tasks(fin, client=active_client(client), progress=progress, desc="recolour"))
    stats = {
        "map_tasks": 0,
        "finish_tasks": len(fin),
        "reused_ray_sums": True,
        "resident": False,
        "gathered_bytes": sum(int(p.nbytes) for p in packed),
        "seconds": time.perf_counter() - t0,
    }
    fields = image_fields(spec, plan, camera, rays.n_samples, meta, sums.tile, level=sums.level)
    return EncryptedImage(ciphertexts=list(packed), stats=stats, **with_colouring(fields, spec))
