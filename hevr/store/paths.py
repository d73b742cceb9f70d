"""Where stores live: local folders or fsspec URLs, and replacing one store by another
without ever losing the old one (write beside, then swap)."""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import shutil
from pathlib import Path
from typing import Any

import zarr

from ..errors import StoreExistsError

log = logging.getLogger(__name__)

__all__ = ["token", "is_local", "store_exists", "sibling", "check_replaceable", "remove_tree", "swap",
           "read_document", "document_digest"]


def token() -> str:
    return secrets.token_hex(4)


def is_local(path: str) -> bool:
    return "://" not in path


def store_exists(path: str) -> bool:
    if is_local(path):
        return Path(path).exists()
    try:
        zarr.open_group(path, mode="r")
        return True
    except Exception:
        return False


def read_document(path: str, name: str) -> bytes:
    """The raw bytes of the Zarr metadata document ``name/zarr.json`` (``zarr.json`` for the
    group when ``name`` is empty) of the store at ``path``, local or fsspec."""
    rel = f"{name}/zarr.json" if name else "zarr.json"
    if is_local(path):
        return (Path(path) / rel).read_bytes()
    fs, root = _fs(path)
    return fs.cat(f"{root.rstrip('/')}/{rel}")


def document_digest(path: str, name: str) -> str:
    """``"sha256:<hex>"`` of a metadata document's exact bytes: every byte counts, since Zarr
    tolerates some damage (a misspelt key falls back to a default)."""
    return "sha256:" + hashlib.sha256(read_document(path, name)).hexdigest()


def sibling(path: str, what: str) -> str:
    """A fresh path beside ``path`` (same folder or bucket prefix) for a new or an old store."""
    if is_local(path):
        p = Path(path)
        return str(p.with_name(f".{p.name}.hevr-{what}-{token()}"))
    return f"{path.rstrip('/')}.hevr-{what}-{token()}"


def check_replaceable(path: str) -> None:
    """``overwrite=True`` replaces only an hevr (Zarr) store, never another folder or a file."""
    if is_local(path):
        p = Path(path)
        if not p.is_dir():
            raise StoreExistsError(f"path: {path} exists and is not a directory; refusing to replace it")
        if not (p / "zarr.json").exists():
            raise StoreExistsError(f"path: {path} exists and is not a Zarr store; refusing to replace it")


def _fs(path: str) -> tuple[Any, str]:
    import fsspec

    fs, _, (root,) = fsspec.get_fs_token_paths(path)
    return fs, root


def remove_tree(path: str) -> None:
    try:
        if is_local(path):
            shutil.rmtree(path)
        else:
            fs, root = _fs(path)
            fs.rm(root, recursive=True)
    except OSError as exc:  # pragma: no cover - best effort after another failure
        log.warning("could not remove %s: %s", path, exc)


def swap(new: str, path: str) -> None:
    """Put the complete store ``new`` at ``path``; the old store is moved aside first and
    deleted only once the new one is in place (restored if the second move fails).

    POSIX has no portable atomic exchange of two folders: if the process is killed between
    the two renames (a window of microseconds locally), ``path`` is missing and both stores
    sit beside it, complete, as ``.NAME.hevr-old-…`` and ``.NAME.hevr-new-…`` (logged first);
    renaming either back restores a store. Nothing is lost either way."""
    old = sibling(path, "old")
    log.info("replacing %s: old store moved to %s, new store %s moved in", path, old, new)
    if is_local(path):
        os.replace(path, old)
        try:
            os.replace(new, path)
        except BaseException:
            os.replace(old, path)
            raise
    else:
        fs, root = _fs(path)
        fs_old, fs_new = _fs(old)[1], _fs(new)[1]
        fs.mv(root, fs_old, recursive=True)
        try:
            fs.mv(fs_new, root, recursive=True)
        except BaseException:
            fs.mv(fs_old, root, recursive=True)
            raise
    remove_tree(old)
