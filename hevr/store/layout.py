"""A store's layout (its arrays, their shapes, chunks and codecs) and the checks that a store
on disk has exactly that layout: every metadata document pinned by a digest in the
checksummed ``hevr`` attribute, every array's settings, every chunk file's size (local
stores). Used by :func:`hevr.open_volume` for level 0 and by
:meth:`hevr.EncryptedVolume.at_level` for a pyramid level (docs/format.md).

No bytes for padding
--------------------
Zarr's regular chunk grid stores every chunk at full size, so a brick on the volume's edge
is padded with the fill value 0 up to the brick shape: the tooth (103 × 94 × 161 voxels in
32³ bricks) stored 51 % zeros. Brick arrays therefore pass through Zarr's standard ``zstd``
codec (level 1) before ``crc32c``. Ciphertexts are uniformly distributed residues, which
zstd stores as raw blocks (a few bytes per 128 KiB block); the zero padding of an edge
brick compresses to almost nothing. The result is a store within 1 % of the ciphertext
bytes, still plain Zarr v3 that any Zarr reader opens, at the cost of one memcpy-speed
pass on read and write (measured in docs/format.md). Stores written before this change
(codecs ``bytes`` + ``crc32c``) remain valid and open unchanged. The ``done`` digest array
has no padding and keeps ``bytes`` + ``crc32c`` with exact chunk sizes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from ..core.files import check_regular
from ..crypto.tags import data_channel, tag_channel
from ..errors import CorruptStoreError, MissingFileError
from .digests import DIGEST_BYTES
from .metadata import VolumeMetadata, ome_attribute
from .paths import document_digest, is_local, object_sizes, read_document, zarr_store
from .zstd_frame import DamagedFrame, frame_length

__all__ = [
    "CRC_BYTES",
    "compressors",
    "array_layout",
    "array_slices",
    "brick_slices",
    "chunk_key",
    "check_entry",
    "check_document",
    "check_arrays",
    "check_chunk_files",
    "check_chunk_objects",
    "check_documents",
    "check_level_layout",
    "store_array",
]

CRC_BYTES = 4  # Zarr's crc32c codec appends 4 bytes to every chunk
ZSTD_LEVEL = 1  # ciphertexts do not compress; level 1 only has to squeeze out the edge padding

# Codec chains an array may have: bricks now, bricks of stores written before zstd, digests.
_BRICK_CODECS, _LEGACY_CODECS = ["bytes", "zstd", "crc32c"], ["bytes", "crc32c"]


def compressors(name: str) -> list[Any]:
    """Zarr ``compressors`` (bytes-to-bytes codecs) of array ``name`` in a new store.

    >>> [c.to_dict()["name"] for c in compressors("scalar")], [c.to_dict()["name"] for c in compressors("done")]
    (['zstd', 'crc32c'], ['crc32c'])
    """
    if name == "done":
        return [Crc32cCodec()]
    return [ZstdCodec(level=ZSTD_LEVEL), Crc32cCodec()]


def array_layout(meta: VolumeMetadata) -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """``{array name: (shape, chunk shape)}`` of every array a store of ``meta`` has; the
    ``done`` array holds one digest per channel per brick (:mod:`hevr.store.digests`)."""
    w = meta.ciphertext_bytes
    out: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {}
    # a packed store's arrays: S voxels per record along its axis (hevr.store.packing)
    shape: tuple[int, ...]
    brick: tuple[int, ...]
    shape, brick = (
        (meta.shape, meta.brick)
        if meta.packing is None
        else (meta.packing.array_shape(meta.shape), meta.packing.array_brick(meta.brick))
    )
    if meta.scalar is not None:
        out["scalar"] = (shape + (w,), brick + (w,))
    for name in ("vector", "gradient"):  # k components per voxel (per pack), one chunk holds all k of a brick
        if getattr(meta, name) is not None:
            k = meta.components(name)
            out[name] = ((k,) + shape + (w,), (k,) + brick + (w,))
    if meta.tags:  # a verifiable store: each channel's tags, laid out as the channel
        out.update({tag_channel(name): out[name] for name in meta.data_channels})
    nch = len(meta.channel_names)
    out["done"] = (meta.grid + (nch, DIGEST_BYTES), (1, 1, 1, nch, DIGEST_BYTES))
    return out


def store_array(group: zarr.Group, name: str) -> zarr.Array[Any]:
    """The array ``name`` of a store's Zarr group (a group in its place is a damaged store)."""
    arr = group[name]
    if not isinstance(arr, zarr.Array):
        raise CorruptStoreError(f"{name}: expected an array of the store, found a group")
    return arr


def brick_slices(meta: VolumeMetadata, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
    """Array slices (z, y, x) of the voxels owned by brick ``index``."""
    return tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(index, meta.brick, meta.shape))  # type: ignore[return-value]


def array_slices(meta: VolumeMetadata, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
    """Slices of brick ``index``'s records in the scalar array (and its tags): the voxel slices of
    a per-voxel store, pack units along the packing axis of a packed one (:mod:`hevr.store.packing`)."""
    if meta.packing is None:
        return brick_slices(meta, index)
    shape, brick = meta.packing.array_shape(meta.shape), meta.packing.array_brick(meta.brick)
    return tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(index, brick, shape))  # type: ignore[return-value]


def chunk_key(name: str, index: tuple[int, ...]) -> str:
    """The key of brick ``index``'s chunk in array ``name`` of a store, relative to the array's
    folder: Zarr v3's default ``c/`` + ``/``-separated chunk coordinates.

    >>> chunk_key("scalar", (0, 1, 2)), chunk_key("vector", (0, 1, 2)), chunk_key("done", (0, 1, 2))
    ('c/0/1/2/0', 'c/0/0/1/2/0', 'c/0/1/2/0/0')
    """
    lead = (0, 0) if name == "done" else (0,)
    vector = data_channel(name) in ("vector", "gradient")
    return "c/" + "/".join(str(int(i)) for i in ((0,) if vector else ()) + tuple(index) + lead)


def check_entry(path: str, rel: str, what: str) -> bool:
    """Whether the file ``rel`` (a chunk or a ``zarr.json``) exists in the local store ``path``
    (``True`` for an object store, whose objects are never FIFOs). Anything there that is not
    a regular file (a FIFO, a folder, a socket, a device: opening or reading it would block or
    fail) is a :class:`hevr.CorruptStoreError` naming ``what`` and the path, found with one
    ``stat``, before Zarr or hevr opens it."""
    if not is_local(path):
        return True
    try:
        check_regular(Path(path) / rel, str(path), what, error=CorruptStoreError)
    except MissingFileError:
        return False
    return True


def check_document(path: str, name: str) -> None:
    """The metadata document ``NAME/zarr.json`` (the group's when ``name`` is empty) of the local
    store ``path`` is a regular file or absent (:func:`check_entry`): call before reading it."""
    rel = f"{name}/zarr.json" if name else "zarr.json"
    check_entry(path, rel, f"the metadata document {rel}")


def check_chunk_files(path: str, meta: VolumeMetadata, prefix: str = "") -> None:
    """Local stores: every brick chunk (and digest marker) exists as a regular file and has
    exactly the expected size (a zstd chunk: its frame's own length plus the crc)."""
    root = Path(path) / prefix
    for name, (_, chunks) in array_layout(meta).items():
        expected = int(np.prod(chunks)) + CRC_BYTES
        # zstd chunks have no fixed size, but a zstd frame records its block sizes: the frame's
        # length is found by reading a 3-byte header every block (128 KiB), not the data
        exact = name == "done" or _codec_names(root / name) == _LEGACY_CODECS
        for idx in np.ndindex(*meta.grid):
            rel = f"{prefix}{name}/{chunk_key(name, idx)}"
            brick = tuple(int(i) for i in idx)
            where = "the digest markers 'done'" if name == "done" else f"channel {name!r}"
            try:
                size = check_regular(
                    Path(path) / rel, str(path), f"the chunk of brick {brick} in {where}", error=CorruptStoreError
                ).st_size
            except MissingFileError:
                raise CorruptStoreError(f"{path}: missing chunk for brick {brick} in {where}") from None
            if not exact:  # the zstd frame's own length (walked from its block headers) + the crc
                try:
                    expected = (
                        frame_length(root / name / chunk_key(name, idx), int(np.prod(chunks)), size - CRC_BYTES)
                        + CRC_BYTES
                    )
                except DamagedFrame as exc:
                    raise CorruptStoreError(
                        f"{path}: chunk {rel} of brick {brick} in {where} is damaged (not a complete zstd frame: {exc})"
                    ) from None
            if size != expected:
                raise CorruptStoreError(
                    f"{path}: chunk {rel} of brick {brick} in {where} is truncated "
                    f"or padded ({size} bytes, expected {expected})"
                )


_GROUP_KEYS = {"attributes": None, "zarr_format": 3, "node_type": "group", "consolidated_metadata": None}


def check_documents(path: str, meta: VolumeMetadata, storage_options: dict[str, Any] | None = None) -> None:
    """Every byte of every metadata document counts (Zarr itself tolerates a misspelt key):
    each array's ``zarr.json`` must have the digest recorded in the checksummed ``hevr``
    attribute, and the group's ``zarr.json`` holds nothing but what hevr wrote."""
    try:
        check_document(path, "")
        doc = json.loads(read_document(path, "", storage_options))
        for name, want in meta.arrays.items():
            try:
                check_document(path, name)
                got = document_digest(path, name, storage_options)
            except FileNotFoundError:
                raise CorruptStoreError(
                    f"{path}: "
                    + (
                        f"channel {name!r} is declared but its array is missing"
                        if name != "done"
                        else "the digest array 'done' is missing"
                    )
                ) from None
            if got != want:
                raise CorruptStoreError(
                    f"{path}: the metadata document of array {name!r} was modified or corrupted (digest mismatch)"
                )
    except (OSError, ValueError) as exc:
        raise CorruptStoreError(f"{path}: a metadata document cannot be read ({type(exc).__name__}: {exc})") from None
    extra = set(doc) - set(_GROUP_KEYS)
    wrong = [k for k, v in _GROUP_KEYS.items() if k != "attributes" and doc.get(k, v) != v]
    attrs = doc.get("attributes", {})
    if meta.levels and attrs.get("ome") != ome_attribute(meta):  # the multiscales follow the metadata
        raise CorruptStoreError(
            f"{path}: the group's 'ome' attribute (OME-Zarr multiscales) does not match the store's pyramid levels"
        )
    if extra or wrong or set(attrs) != ({"hevr", "ome"} if meta.levels else {"hevr"}):
        raise CorruptStoreError(
            f"{path}: the group's zarr.json has unexpected content "
            f"({sorted(extra) + wrong or 'attributes other than hevr'})"
        )


def check_level_layout(view: Any) -> None:
    """A level's arrays: their documents' digests as recorded in the (checksummed) metadata,
    their layout, and (local stores) every chunk file's size — what open_volume checks of level 0."""
    path, meta, prefix, so = view.path, view.meta, view.prefix, view.storage_options
    for name, want in meta.arrays.items():
        try:
            check_document(path, prefix + name)
            got = document_digest(path, prefix + name, so)
        except (OSError, ValueError):
            raise CorruptStoreError(
                f"{path}: array {prefix + name!r} of pyramid level {view.level} is missing"
            ) from None
        if got != want:
            raise CorruptStoreError(
                f"{path}: the metadata document of array {prefix + name!r} was modified or corrupted (digest mismatch)"
            )
    try:
        group = zarr.open_group(zarr_store(path, so, read_only=True), path=prefix.rstrip("/"), mode="r")
    except Exception as exc:
        raise CorruptStoreError(
            f"{path}: pyramid level {view.level} cannot be opened ({type(exc).__name__}: {exc})"
        ) from None
    check_arrays(path, group, meta)
    if is_local(path):
        check_chunk_files(path, meta, prefix)
    else:
        check_chunk_objects(path, meta, prefix, so)


def check_arrays(path: str, group: Any, meta: VolumeMetadata) -> None:
    """Every array the metadata implies exists with exactly the layout hevr writes: shape,
    chunk shape, uint8, fill value 0, codecs ``bytes`` + ``zstd`` + ``crc32c`` (bricks of stores
    written before zstd: ``bytes`` + ``crc32c``; ``done``: ``bytes`` + ``crc32c``), no attributes."""
    for name, (shape, chunks) in array_layout(meta).items():
        try:  # a missing array was named by check_documents already
            arr = group[name]
        except Exception as exc:
            raise CorruptStoreError(f"{path}: array {name!r} cannot be opened ({type(exc).__name__}: {exc})") from None
        codecs = [c.to_dict().get("name") for c in arr.metadata.codecs] if hasattr(arr.metadata, "codecs") else None
        got = (tuple(arr.shape), tuple(arr.chunks), str(arr.dtype), arr.metadata.fill_value, codecs, dict(arr.attrs))
        want: tuple[Any, ...] = (
            shape,
            chunks,
            "uint8",
            0,
            _LEGACY_CODECS if name == "done" or codecs == _LEGACY_CODECS else _BRICK_CODECS,
            {},
        )
        if got != want or getattr(arr.metadata, "dimension_names", None) is not None:
            labels = ("shape", "chunks", "dtype", "fill_value", "codecs", "attributes")
            diff = "; ".join(f"{lab} {g!r} (expected {w!r})" for lab, g, w in zip(labels, got, want) if g != w)
            raise CorruptStoreError(
                f"{path}: array {name!r} has {diff or 'dimension names'}, inconsistent with the metadata"
            )


def _codec_names(array_dir: Path) -> list[str] | None:
    """The codec names in a local array's ``zarr.json`` (its digest was checked before)."""
    try:
        return [c.get("name") for c in json.loads((array_dir / "zarr.json").read_text()).get("codecs", [])]
    except (OSError, ValueError, AttributeError):
        return None


def check_chunk_objects(
    path: str, meta: VolumeMetadata, prefix: str = "", storage_options: dict[str, Any] | None = None
) -> None:
    """Object stores: what :func:`check_chunk_files` checks of a local store, from one listing
    per array (no object is read): every brick chunk and digest marker exists; a ``done`` chunk
    and an uncompressed (``bytes`` + ``crc32c``) brick chunk have exactly the expected size; a
    zstd brick chunk lies between the smallest zstd frame plus the crc and the raw bytes plus
    zstd's worst-case overhead (3 bytes per 128 KiB block, an 18-byte header) plus the crc. A
    chunk that passes this but is damaged still fails its crc32c and its brick digest on read."""
    for name, (_, chunks) in array_layout(meta).items():
        raw = int(np.prod(chunks))
        try:
            codecs = [c.get("name") for c in json.loads(read_document(path, prefix + name, storage_options))["codecs"]]
            sizes = object_sizes(f"{path}/{prefix}{name}/c", storage_options)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise CorruptStoreError(
                f"{path}: array {prefix + name!r} cannot be listed ({type(exc).__name__})"
            ) from None
        exact = name == "done" or codecs == _LEGACY_CODECS
        lo, hi = (raw + CRC_BYTES,) * 2 if exact else (CRC_BYTES + 6, raw + 3 * (raw // 131072 + 1) + 18 + CRC_BYTES)
        where = "the digest markers 'done'" if name == "done" else f"channel {name!r}"
        for idx in np.ndindex(*meta.grid):
            key = chunk_key(name, idx)[len("c/") :]
            brick = tuple(int(i) for i in idx)
            size = sizes.get(key)
            if size is None:
                raise CorruptStoreError(f"{path}: missing chunk for brick {brick} in {where}")
            if not lo <= size <= hi:
                raise CorruptStoreError(
                    f"{path}: chunk of brick {brick} in {where} is truncated or padded "
                    f"({size} bytes, expected {lo if exact else f'{lo} to {hi}'})"
                )
