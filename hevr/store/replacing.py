"""Replacing one store by another without ever losing the old one: the new store is written beside
the old (:func:`sibling`), and :func:`swap` puts it in place, moving the old one aside first and
deleting it only once the new one is in. Only an hevr store is ever replaced
(:func:`check_replaceable`); a failed new store is removed (:func:`remove_tree`).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..core.files import fs_errors
from ..core.siblings import temp_sibling
from ..errors import StoreExistsError
from .exclusive import lock_store, remove_local_tree, rename_noreplace, swap_lock
from .metadata import FORMAT_NAME
from .paths import filesystem, is_local, read_document, token

log = logging.getLogger(__name__)

__all__ = ["check_replaceable", "remove_tree", "sibling", "swap"]


def sibling(path: str, what: str) -> str:
    """A fresh path beside ``path`` (same folder or bucket prefix) for a new or an old store:
    locally ``.NAME.hevr-WHAT-TOKEN`` (:func:`hevr.core.siblings.temp_sibling`)."""
    if is_local(path):
        return str(temp_sibling(path, what))
    return f"{path.rstrip('/')}.hevr-{what}-{token()}"


def check_replaceable(path: str, storage_options: dict[str, Any] | None = None) -> str:
    """``overwrite=True`` replaces only an hevr store (any format version), never another
    folder, file, Zarr group or prefix; returns its ``store_id`` ('' if it has none)."""
    if is_local(path) and not Path(path).is_dir():
        raise StoreExistsError(f"path: {path} exists and is not a directory; refusing to replace it")
    try:
        attrs = json.loads(read_document(path, "", storage_options)).get("attributes", {}).get("hevr", {})
        ok = isinstance(attrs, dict) and attrs.get("format") == FORMAT_NAME
    except (OSError, ValueError, AttributeError):
        ok, attrs = False, {}
    if not ok:
        raise StoreExistsError(
            f"path: {path} exists and is not an hevr store (no readable zarr.json with an "
            "'hevr' attribute); refusing to replace it"
        )
    store_id = attrs.get("store_id", "")
    return store_id if isinstance(store_id, str) else ""


def remove_tree(path: str, storage_options: dict[str, Any] | None = None) -> None:
    """Remove the store ``path`` after a failure: best effort (logged), a local tree retried
    (:func:`hevr.store.exclusive.remove_local_tree`)."""
    try:
        if is_local(path):
            remove_local_tree(path)
        else:
            fs, root = filesystem(path, storage_options)
            fs.rm(root, recursive=True)
    except OSError as exc:  # pragma: no cover - best effort after another failure
        log.warning("could not remove %s: %s", path, exc)


def swap(
    new: str,
    path: str,
    storage_options: dict[str, Any] | None = None,
    *,
    lock: Any = None,
    then: Callable[[], Any] | None = None,
) -> tuple[str, Any]:
    """Put the complete store ``new`` at ``path``; the old store is moved aside first and
    deleted only once the new one is in place (restored if the second move fails). Returns
    the replaced store's ``store_id`` and what ``then()`` (run right after the swap) returned.

    Locally the swap holds :func:`hevr.store.exclusive.swap_lock` (one swap at a time in a
    folder) and the replaced store's own lock (a store that another run is writing right now
    is never swapped out: :class:`hevr.StoreExistsError`); ``then`` runs and ``lock`` (the
    caller's lock of ``new``) is released before the folder's lock is, so a concurrent
    overwrite finds the swapped-in store complete and free. Moves into ``path`` never replace
    anything (:func:`hevr.store.exclusive.rename_noreplace`).

    POSIX has no portable atomic exchange of two folders: if the process is killed between
    the two renames (a window of microseconds locally), ``path`` is missing and both stores
    sit beside it, complete, as ``.NAME.hevr-old-…`` and ``.NAME.hevr-new-…`` (logged first);
    renaming either back restores a store. Nothing is lost either way. On an object store a
    move is a copy of every object and a delete (no rename exists there), so an overwrite
    copies the store twice; the same two steps keep the old store until the new one is in;
    concurrent overwrites of one URL are not serialised there (the last one wins)."""
    old = sibling(path, "old")
    if is_local(path):
        with fs_errors("replacing the store", path):
            with swap_lock(path):
                held = lock_store(path)
                try:
                    old_id = check_replaceable(path, storage_options)
                    log.info("replacing %s: old store moved to %s, new store %s moved in", path, old, new)
                    os.rename(path, old)
                    try:
                        rename_noreplace(new, path)
                    except BaseException:
                        rename_noreplace(old, path)
                        raise
                    result = then() if then is not None else None
                    if lock is not None:
                        lock.release()
                except BaseException:
                    held.release()
                    raise
            with held:  # the old store stays locked while it is removed (a clean-up keeps off)
                remove_local_tree(old)
        return old_id, result
    old_id = check_replaceable(path, storage_options)
    log.info("replacing %s: old store moved to %s, new store %s moved in", path, old, new)
    fs, root = filesystem(path, storage_options)
    fs_old, fs_new = filesystem(old, storage_options)[1], filesystem(new, storage_options)[1]
    _move_objects(fs, root, fs_old)
    try:
        _move_objects(fs, fs_new, root)
    except BaseException:
        _move_objects(fs, fs_old, root)
        raise
    result = then() if then is not None else None
    remove_tree(old, storage_options)
    return old_id, result


def _move_objects(fs: Any, src: str, dst: str) -> None:
    """Move every object under ``src`` to the same key under ``dst``: copy all, then delete all
    (``fs.mv(recursive=True)`` would also try to copy S3's pseudo-folders, which are no objects)."""
    src, dst = src.rstrip("/"), dst.rstrip("/")
    fs.invalidate_cache(src)
    files = [f for f in fs.find(src) if f.startswith(src + "/")]
    if files:
        fs.copy(files, [dst + f[len(src) :] for f in files])
        fs.rm(files)
    fs.invalidate_cache(src)
    fs.invalidate_cache(dst)
