"""A store's layout (its arrays, their shapes and chunks) and the checks that a store on disk
has exactly that layout: every metadata document pinned by a digest in the checksummed
``hevr`` attribute, every array's settings, every chunk file's size (local stores). Used by
:func:`hevr.open_volume` for level 0 and by :meth:`hevr.EncryptedVolume.at_level` for a
pyramid level (docs/format.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..errors import CorruptStoreError
from .digests import DIGEST_BYTES
from .metadata import VolumeMetadata, ome_attribute
from .paths import document_digest, read_document

__all__ = ["CRC_BYTES", "array_layout", "brick_slices", "check_arrays", "check_chunk_files", "check_documents",
           "check_level_layout"]

CRC_BYTES = 4  # Zarr's crc32c codec appends 4 bytes to every chunk


def array_layout(meta: VolumeMetadata) -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """``{array name: (shape, chunk shape)}`` of every array a store of ``meta`` has; the
    ``done`` array holds one digest per channel per brick (:mod:`hevr.store.digests`)."""
    w, out = meta.ciphertext_bytes, {}
    if meta.scalar is not None:
        out["scalar"] = (meta.shape + (w,), meta.brick + (w,))
    for name in ("vector", "gradient"):  # k components per voxel, one chunk holds all k of a brick
        if getattr(meta, name) is not None:
            k = meta.components(name)
            out[name] = ((k,) + meta.shape + (w,), (k,) + meta.brick + (w,))
    nch = len(meta.channel_names)
    out["done"] = (meta.grid + (nch, DIGEST_BYTES), (1, 1, 1, nch, DIGEST_BYTES))
    return out


def brick_slices(meta: VolumeMetadata, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
    """Array slices (z, y, x) of the voxels owned by brick ``index``."""
    return tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(index, meta.brick, meta.shape))  # type: ignore[return-value]


def check_chunk_files(path: str, meta: VolumeMetadata, prefix: str = "") -> None:
    """Local stores: every brick chunk (and digest marker) exists and has exactly the expected size."""
    root = Path(path) / prefix
    for name, (_, chunks) in array_layout(meta).items():
        expected = int(np.prod(chunks)) + CRC_BYTES
        lead = (0, 0) if name == "done" else (0,)
        for idx in np.ndindex(*meta.grid):
            key = "/".join(str(i) for i in ((0,) if name in ("vector", "gradient") else ()) + tuple(idx) + lead)
            f = root / name / "c" / key
            brick = tuple(int(i) for i in idx)
            where = "the digest markers 'done'" if name == "done" else f"channel {name!r}"
            if not f.exists():
                raise CorruptStoreError(f"{path}: missing chunk for brick {brick} in {where}")
            size = f.stat().st_size
            if size != expected:
                raise CorruptStoreError(f"{path}: chunk of brick {brick} in {where} is truncated "
                                        f"or padded ({size} bytes, expected {expected})")


_GROUP_KEYS = {"attributes": None, "zarr_format": 3, "node_type": "group", "consolidated_metadata": None}


def check_documents(path: str, meta: VolumeMetadata) -> None:
    """Every byte of every metadata document counts (Zarr itself tolerates a misspelt key):
    each array's ``zarr.json`` must have the digest recorded in the checksummed ``hevr``
    attribute, and the group's ``zarr.json`` holds nothing but what hevr wrote."""
    try:
        doc = json.loads(read_document(path, ""))
        for name, want in meta.arrays.items():
            try:
                got = document_digest(path, name)
            except FileNotFoundError:
                raise CorruptStoreError(f"{path}: " + (f"channel {name!r} is declared but its array is missing"
                                        if name != "done" else "the digest array 'done' is missing")) from None
            if got != want:
                raise CorruptStoreError(f"{path}: the metadata document of array {name!r} was modified or "
                                        "corrupted (digest mismatch)")
    except (OSError, ValueError) as exc:
        raise CorruptStoreError(f"{path}: a metadata document cannot be read ({type(exc).__name__}: {exc})") from None
    extra = set(doc) - set(_GROUP_KEYS)
    wrong = [k for k, v in _GROUP_KEYS.items() if k != "attributes" and doc.get(k, v) != v]
    attrs = doc.get("attributes", {})
    if meta.levels and attrs.get("ome") != ome_attribute(meta):  # the multiscales follow the metadata
        raise CorruptStoreError(f"{path}: the group's 'ome' attribute (OME-Zarr multiscales) does not match "
                                "the store's pyramid levels")
    if extra or wrong or set(attrs) != ({"hevr", "ome"} if meta.levels else {"hevr"}):
        raise CorruptStoreError(f"{path}: the group's zarr.json has unexpected content "
                                f"({sorted(extra) + wrong or 'attributes other than hevr'})")


def check_level_layout(view: Any) -> None:
    """A level's arrays: their documents' digests as recorded in the (checksummed) metadata,
    their layout, and (local stores) every chunk file's size — what open_volume checks of level 0."""
    path, meta, prefix = view.path, view.meta, view.prefix
    for name, want in meta.arrays.items():
        try:
            got = document_digest(path, prefix + name)
        except (OSError, ValueError):
            raise CorruptStoreError(f"{path}: array {prefix + name!r} of pyramid level {view.level} is missing") from None
        if got != want:
            raise CorruptStoreError(f"{path}: the metadata document of array {prefix + name!r} was modified or "
                                    "corrupted (digest mismatch)")
    try:
        group = zarr.open_group(f"{path}/{prefix.rstrip('/')}", mode="r")
    except Exception as exc:
        raise CorruptStoreError(f"{path}: pyramid level {view.level} cannot be opened ({type(exc).__name__}: {exc})") from None
    check_arrays(path, group, meta)
    if "://" not in path:
        check_chunk_files(path, meta, prefix)


def check_arrays(path: str, group: Any, meta: VolumeMetadata) -> None:
    """Every array the metadata implies exists with exactly the layout hevr writes: shape,
    chunk shape, uint8, fill value 0, codecs ``bytes`` + ``crc32c``, no attributes."""
    for name, (shape, chunks) in array_layout(meta).items():
        try:  # a missing array was named by check_documents already
            arr = group[name]
        except Exception as exc:
            raise CorruptStoreError(f"{path}: array {name!r} cannot be opened ({type(exc).__name__}: {exc})") from None
        codecs = [c.to_dict().get("name") for c in arr.metadata.codecs] if hasattr(arr.metadata, "codecs") else None
        got = (tuple(arr.shape), tuple(arr.chunks), str(arr.dtype), arr.metadata.fill_value, codecs, dict(arr.attrs))
        want = (shape, chunks, "uint8", 0, ["bytes", "crc32c"], {})
        if got != want or getattr(arr.metadata, "dimension_names", None) is not None:
            labels = ("shape", "chunks", "dtype", "fill_value", "codecs", "attributes")
            diff = "; ".join(f"{lab} {g!r} (expected {w!r})" for lab, g, w in zip(labels, got, want) if g != w)
            raise CorruptStoreError(f"{path}: array {name!r} has {diff or 'dimension names'}, inconsistent with the metadata")
