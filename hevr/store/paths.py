"""Where stores live: local folders or fsspec URLs, and replacing one store by another
without ever losing the old one (write beside, then swap)."""

from __future__ import annotations

import json
import logging
import os
import secrets
import shutil
from pathlib import Path
from typing import Any

from ..errors import StoreExistsError
from .metadata import FORMAT_NAME, sha256_tag

log = logging.getLogger(__name__)

__all__ = ["token", "is_local", "normalise", "store_exists", "interrupted_swaps", "sibling", "check_replaceable",
           "remove_tree", "swap", "read_document", "document_digest"]


def token() -> str:
    return secrets.token_hex(4)


def is_local(path: str) -> bool:
    return "://" not in path


def normalise(path: str | os.PathLike) -> str:
    """The one spelling of a store path: local paths absolute and resolved (workers may run
    elsewhere), URLs without a trailing slash (``memory://x/`` and ``memory://x`` are one store).

    >>> normalise("memory://bucket/v.zarr/")
    'memory://bucket/v.zarr'
    """
    text = str(path)
    return str(Path(text).resolve()) if is_local(text) else text.rstrip("/")


def store_exists(path: str) -> bool:
    """Whether anything at all is at ``path`` (a folder, a file, or any object under a URL
    prefix): such a path is never written over without ``overwrite=True``."""
    if is_local(path):
        return Path(path).exists() or Path(path).is_symlink()
    fs, root = _fs(path)
    return bool(fs.exists(root))


def interrupted_swaps(path: str) -> list[str]:
    """Stores an interrupted overwrite left beside a local ``path`` (see :func:`swap`)."""
    if not is_local(path):
        return []
    p = Path(path)
    try:
        return sorted(str(q) for q in p.parent.glob(f".{p.name}.hevr-*-*") if q.name.split(".hevr-")[1][:4] in
                      ("old-", "new-"))
    except OSError:
        return []


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
    return sha256_tag(read_document(path, name))


def sibling(path: str, what: str) -> str:
    """A fresh path beside ``path`` (same folder or bucket prefix) for a new or an old store."""
    if is_local(path):
        p = Path(path)
        return str(p.with_name(f".{p.name}.hevr-{what}-{token()}"))
    return f"{path.rstrip('/')}.hevr-{what}-{token()}"


def check_replaceable(path: str) -> str:
    """``overwrite=True`` replaces only an hevr store (any format version), never another
    folder, file, Zarr group or prefix; returns its ``store_id`` ('' if it has none)."""
    if is_local(path) and not Path(path).is_dir():
        raise StoreExistsError(f"path: {path} exists and is not a directory; refusing to replace it")
    try:
        attrs = json.loads(read_document(path, "")).get("attributes", {}).get("hevr", {})
        ok = isinstance(attrs, dict) and attrs.get("format") == FORMAT_NAME
    except (OSError, ValueError, AttributeError):
        ok, attrs = False, {}
    if not ok:
        raise StoreExistsError(f"path: {path} exists and is not an hevr store (no readable zarr.json with an "
                               "'hevr' attribute); refusing to replace it")
    store_id = attrs.get("store_id", "")
    return store_id if isinstance(store_id, str) else ""


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
