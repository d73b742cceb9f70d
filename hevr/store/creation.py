"""Creating a new store: exactly one of several concurrent creators of one path wins.

:func:`claim_store` builds a new store's skeleton (group, arrays, metadata marked
incomplete) and puts it at ``path`` only if nothing is there: locally through a locked
temporary sibling and a rename that never replaces anything (:mod:`hevr.store.exclusive`),
on a URL by claiming the group's ``zarr.json`` with an exclusive create (guarantees in
:func:`claim_store`). The loser gets :class:`hevr.StoreExistsError` and writes nothing at
``path``; the winner keeps the store's lock until its run ends (:func:`hevr.encrypt_volume`).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import threading
from pathlib import Path

import numpy as np
import zarr

from ..core.files import check_name, fs_errors
from ..errors import ExistingFileError, FileSystemError, ParameterError, StoreError, StoreExistsError
from .exclusive import StoreLock, locked_folder, remove_local_tree, rename_noreplace, swap_lock
from .layout import check_document, check_documents, check_entry, chunk_key, compressors
from .metadata import VolumeMetadata
from .paths import document_digest, filesystem, is_local, read_document, write_new_bytes, zarr_store
from .reader import array_layout
from .replacing import sibling

__all__ = ["create_store", "claim_store", "new_store", "resume_target"]

_URL_CLAIMS = threading.Lock()  # memory:// lives in this process: its claims are atomic under this lock


def create_store(
    path: str, meta: VolumeMetadata, storage_options: dict | None = None, *, name: str = "path"
) -> VolumeMetadata:
    """Create a new store at ``path`` exclusively (:func:`claim_store`; its lock is not kept).
    Returns the metadata written."""
    meta, lock = claim_store(path, meta, storage_options, name=name)
    lock.release()
    return meta


def claim_store(
    path: str, meta: VolumeMetadata, storage_options: dict | None = None, *, name: str = "path"
) -> tuple[VolumeMetadata, StoreLock]:
    """Create the group and arrays of a new store (incomplete) at ``path``, only if nothing is
    there: of several creators exactly one wins, the others get :class:`hevr.StoreExistsError`
    naming ``name`` and nothing of theirs is written there. Returns the metadata written and
    the store's lock, held (:mod:`hevr.store.exclusive`; nothing is held for a URL).

    On a URL the claim is the group's ``zarr.json``, written first with fsspec's exclusive
    create (``pipe_file(mode="create")``): atomic on S3 with conditional writes (s3fs sends
    ``If-None-Match: *``) and on ``memory://`` (under a lock of this process); elsewhere a
    check just before the write. The claim is read back before anything else is written: a
    creator that finds another's ``store_id`` there gets StoreExistsError. Where the create
    is not atomic two creators starting within one request of each other can both pass; then
    each checks again before it returns (:func:`encrypt_volume`), so at most the last one to
    write ``zarr.json`` returns success, but the winner's bricks may be mixed with the
    loser's: ``verify="full"`` tells."""
    if not is_local(path):
        with fs_errors("creating the store", path):
            _claim_url(path, meta, storage_options, name)
            _check_owner(path, meta.store_id, storage_options, name)
            return _skeleton(path, meta, storage_options, claimed=True), StoreLock(None)
    check_name(path, name)
    with fs_errors("creating the store", path):
        parent = Path(path).parent
        if not parent.is_dir() and (parent.exists() or parent.is_symlink()):
            raise FileSystemError(errno.ENOTDIR, "creating the store", path)
        parent.mkdir(parents=True, exist_ok=True)
        tmp, lock = locked_folder(path, "tmp")
        try:
            meta = _skeleton(tmp, meta, None)
            with swap_lock(path):  # never in the instant a swap has moved the old store aside
                rename_noreplace(tmp, path)
        except BaseException as exc:
            remove_local_tree(tmp)
            lock.release()
            if isinstance(exc, FileExistsError) and not isinstance(exc, StoreError):
                raise StoreExistsError(
                    f"{name}: {path} already exists (created by another run at the same time); "
                    "nothing was written there"
                ) from None
            raise
    return meta, lock


def _claim_url(path: str, meta: VolumeMetadata, storage_options: dict | None, name: str) -> None:
    """Write the group's ``zarr.json`` at the URL ``path`` if no object is there (claim_store)."""
    fs, root = filesystem(path, storage_options)
    doc = json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {"hevr": meta.to_dict()}}).encode()
    with _URL_CLAIMS:
        fs.invalidate_cache(root)
        try:  # the conditional create of hevr.store.paths.write_new_bytes
            write_new_bytes(f"{path.rstrip('/')}/zarr.json", [doc], storage_options, name=name)
        except ExistingFileError:
            raise StoreExistsError(
                f"{name}: {path} already exists (created by another run at the same time); nothing was written there"
            ) from None


def _check_owner(path: str, store_id: str, storage_options: dict | None, name: str) -> None:
    """Raise :class:`hevr.StoreExistsError` unless the store at ``path`` is the one of ``store_id``."""
    try:
        found = json.loads(read_document(path, "", storage_options))["attributes"]["hevr"]["store_id"]
    except (OSError, ValueError, KeyError, TypeError):
        found = None
    if found != store_id:
        raise StoreExistsError(
            f"{name}: {path} was created or replaced by another run at the same time (its store "
            f"id is not this run's); this run stopped"
        )


def _skeleton(path: str, meta: VolumeMetadata, storage_options: dict | None, claimed: bool = False) -> VolumeMetadata:
    """Create the group (``claimed``: its ``zarr.json`` is there already) and its arrays in the
    empty ``path``; record the digest of each array's metadata document in the (checksummed)
    ``hevr`` attribute, written last. Returns the metadata written."""
    group = zarr.open_group(zarr_store(path, storage_options), mode="r+" if claimed else "w-")
    for name, (shape, chunks) in array_layout(meta).items():
        group.create_array(name, shape=shape, chunks=chunks, dtype="uint8", compressors=compressors(name), fill_value=0)
    meta = dataclasses.replace(
        meta, arrays={name: document_digest(path, name, storage_options) for name in array_layout(meta)}
    )
    group.attrs["hevr"] = meta.to_dict()
    return meta


def new_store(path: str, meta: VolumeMetadata, so: dict | None, beside: bool) -> tuple[str, VolumeMetadata, StoreLock]:
    """Create the new store: at ``path`` (:func:`claim_store`), or ``beside`` it for an
    overwrite (a locked ``.NAME.hevr-new-TOKEN`` folder, or a URL sibling); returns where,
    the metadata written and the lock held on it."""
    if not beside:
        meta, lock = claim_store(path, meta, so)
        return path, meta, lock
    if not is_local(path):
        target = sibling(path, "new")
        meta, lock = claim_store(target, meta, so)
        return target, meta, lock
    with fs_errors("creating the new store beside", path):
        target, lock = locked_folder(path, "new")
        try:
            return target, _skeleton(target, meta, None), lock
        except BaseException:
            remove_local_tree(target)
            lock.release()
            raise


def resume_target(path: str, meta: VolumeMetadata, storage_options: dict | None = None) -> VolumeMetadata:
    """The metadata of the interrupted store at ``path`` that ``resume=True`` finishes, refused
    (:class:`hevr.ParameterError`) unless the run's key and layout ``meta`` match it."""
    try:
        check_document(path, "")  # a FIFO in place of a document or a marker would block Zarr's read
        group = zarr.open_group(zarr_store(path, storage_options, read_only=True), mode="r")
        old = VolumeMetadata.from_dict(dict(group.attrs).get("hevr"), where=path)
        check_documents(path, old, storage_options)
        for idx in np.ndindex(*old.grid):  # the markers resume reads (absent ones are bricks to do)
            check_entry(path, f"done/{chunk_key('done', idx)}", f"the digest marker of brick {idx}")
    except StoreError:
        raise
    except Exception as exc:
        raise StoreError(f"resume: cannot open the existing store {path}: {exc}") from None
    if old.fingerprint != meta.fingerprint:
        raise ParameterError(
            f"key: the store {path} was started with key {old.fingerprint[:16]}…, got key {meta.fingerprint[:16]}…"
        )
    for name in ("shape", "brick", "spacing", "scalar", "vector", "gradient", "value_range", "dtype", "tags"):
        if getattr(old, name) != getattr(meta, name):
            raise ParameterError(
                f"{name}: resume needs the same {name} as the interrupted run ({getattr(old, name)!r}), "
                f"got {getattr(meta, name)!r}"
            )
    return old
