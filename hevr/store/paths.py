"""Where stores live: local folders or fsspec URLs, and replacing one store by another
without ever losing the old one (write beside, then swap).

A location is a path string plus ``storage_options`` (a dict or None): a local path (or a
``file://`` URL, which :func:`normalise` turns into the local path, so local stores keep their
fast paths and chunk-file checks), or an fsspec URL (``s3://``, ``gs://``, ``az://``,
``memory://`` …) with the options of its filesystem (endpoint, credentials, …). The options are
those of the object store, never hevr key material; they travel with an
:class:`hevr.EncryptedVolume` into the Dask tasks that read the store, and are never written
into a message, a log line or a ``repr`` (paths are). Options given with a local path are
ignored. :func:`zarr_store` and :func:`filesystem` are the one way hevr opens a location.

``memory://`` stores live in the memory of this process: workers of a distributed cluster
in other processes cannot see them, so :func:`check_reachable` refuses them there (an
in-process cluster, ``LocalCluster(processes=False)``, shares this process and is fine).
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import shutil
from pathlib import Path
from typing import Any

from zarr.storage import FsspecStore

from ..errors import MissingDependencyError, ParameterError, StoreExistsError
from .metadata import FORMAT_NAME, sha256_tag

log = logging.getLogger(__name__)

__all__ = ["token", "is_local", "normalise", "store_exists", "interrupted_swaps", "sibling", "check_replaceable",
           "remove_tree", "swap", "read_document", "document_digest", "check_storage_options", "filesystem",
           "zarr_store", "check_reachable", "read_bytes", "write_bytes", "object_sizes"]


def token() -> str:
    return secrets.token_hex(4)


def is_local(path: str) -> bool:
    return "://" not in path


def normalise(path: str | os.PathLike) -> str:
    """The one spelling of a store path: local paths (and ``file://`` URLs) absolute and
    resolved (workers may run elsewhere), URLs without a trailing slash (``memory://x/`` and
    ``memory://x`` are one store).

    >>> normalise("memory://bucket/v.zarr/")
    'memory://bucket/v.zarr'
    >>> normalise("file://" + str(Path("v.zarr").resolve())) == normalise("v.zarr")
    True
    """
    text = str(path)
    if text[:7].lower() == "file://":
        text = text[7:]
        if text.startswith("localhost/"):
            text = text[len("localhost"):]
    return str(Path(text).resolve()) if is_local(text) else text.rstrip("/")


def check_storage_options(storage_options: Any) -> dict[str, Any] | None:
    """``storage_options`` as hevr takes it: None or a dict with string keys (the fsspec
    filesystem's keyword arguments); anything else is a :class:`hevr.ParameterError` (the
    message names the type only, never a value: values may be credentials).

    >>> check_storage_options({"anon": True})
    {'anon': True}
    """
    if storage_options is None:
        return None
    if not isinstance(storage_options, dict) or not all(isinstance(k, str) for k in storage_options):
        raise ParameterError(f"storage_options: expected a dict of fsspec options with string keys or None, "
                             f"got {type(storage_options).__name__}")
    return dict(storage_options)


def filesystem(path: str, storage_options: dict[str, Any] | None = None) -> tuple[Any, str]:
    """The fsspec filesystem of the URL ``path`` (with ``storage_options``) and the path
    inside it."""
    try:
        import fsspec.core
    except ImportError:
        raise MissingDependencyError(f"path: {path} is a URL; reading it needs fsspec "
                                     "(pip install 'hevr[cloud]')") from None
    try:
        fs, root = fsspec.core.url_to_fs(path, **(storage_options or {}))
    except ImportError as exc:  # fsspec names the package of the protocol (s3fs, gcsfs, adlfs)
        raise MissingDependencyError(f"path: {path} needs a filesystem package that is not installed "
                                     f"({exc})") from None
    return fs, root


def zarr_store(path: str, storage_options: dict[str, Any] | None = None, *, read_only: bool = False) -> Any:
    """What ``zarr.open_group`` / ``zarr.open_array`` take as their store for ``path``: the
    local path itself, or a ``zarr.storage.FsspecStore`` of the URL with ``storage_options``."""
    if is_local(path):
        return path
    filesystem(path, storage_options)  # a clear error for a missing filesystem package
    return FsspecStore.from_url(path, storage_options=dict(storage_options or {}), read_only=read_only)


def check_reachable(path: str, client: Any) -> None:
    """Refuse a ``memory://`` store when the tasks run on a distributed cluster whose workers
    are other processes (module docstring); ``client`` is the active client or None."""
    if client is None or not path.lower().startswith("memory://"):
        return
    address = str(getattr(getattr(client, "scheduler", None), "address", "") or "")
    if address.startswith("inproc://"):  # the workers are threads of this process
        return
    raise ParameterError(f"path: {path}: memory:// stores live in this process; workers of a distributed "
                         "cluster cannot see them — use a local path or an object store URL")


def store_exists(path: str, storage_options: dict[str, Any] | None = None) -> bool:
    """Whether anything at all is at ``path`` (a folder, a file, or any object under a URL
    prefix): such a path is never written over without ``overwrite=True``."""
    if is_local(path):
        return Path(path).exists() or Path(path).is_symlink()
    fs, root = filesystem(path, storage_options)
    fs.invalidate_cache(root)
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


def read_document(path: str, name: str, storage_options: dict[str, Any] | None = None) -> bytes:
    """The raw bytes of the Zarr metadata document ``name/zarr.json`` (``zarr.json`` for the
    group when ``name`` is empty) of the store at ``path``, local or fsspec."""
    rel = f"{name}/zarr.json" if name else "zarr.json"
    if is_local(path):
        return (Path(path) / rel).read_bytes()
    return read_bytes(f"{path.rstrip('/')}/{rel}", storage_options)


def document_digest(path: str, name: str, storage_options: dict[str, Any] | None = None) -> str:
    """``"sha256:<hex>"`` of a metadata document's exact bytes: every byte counts, since Zarr
    tolerates some damage (a misspelt key falls back to a default)."""
    return sha256_tag(read_document(path, name, storage_options))


def read_bytes(path: str, storage_options: dict[str, Any] | None = None) -> bytes:
    """The bytes of the file or object ``path`` (local, or a URL); ``FileNotFoundError`` if absent."""
    if is_local(path):
        return Path(path).read_bytes()
    fs, root = filesystem(path, storage_options)
    return fs.cat_file(root)


def write_bytes(path: str, parts: Any, storage_options: dict[str, Any] | None = None) -> None:
    """Write the concatenated ``parts`` to the object ``path`` in one request: an object store
    makes an object visible whole or not at all (what the local ``<path>.tmp`` + rename gives)."""
    fs, root = filesystem(path, storage_options)
    fs.pipe_file(root, b"".join(parts))


def object_sizes(path: str, storage_options: dict[str, Any] | None = None) -> dict[str, int]:
    """``{key relative to path: size in bytes}`` of every object under the URL ``path``, from
    one listing (``fs.find``: one LIST request per 1000 objects on S3)."""
    fs, root = filesystem(path, storage_options)
    root = root.rstrip("/")
    fs.invalidate_cache(root)  # a listing cached by this process may predate other writers
    found = fs.find(root, detail=True)
    return {k[len(root) + 1:]: int(v.get("size") or 0) for k, v in found.items() if k.startswith(root + "/")}


def sibling(path: str, what: str) -> str:
    """A fresh path beside ``path`` (same folder or bucket prefix) for a new or an old store."""
    if is_local(path):
        p = Path(path)
        return str(p.with_name(f".{p.name}.hevr-{what}-{token()}"))
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
        raise StoreExistsError(f"path: {path} exists and is not an hevr store (no readable zarr.json with an "
                               "'hevr' attribute); refusing to replace it")
    store_id = attrs.get("store_id", "")
    return store_id if isinstance(store_id, str) else ""


def remove_tree(path: str, storage_options: dict[str, Any] | None = None) -> None:
    try:
        if is_local(path):
            shutil.rmtree(path)
        else:
            fs, root = filesystem(path, storage_options)
            fs.rm(root, recursive=True)
    except OSError as exc:  # pragma: no cover - best effort after another failure
        log.warning("could not remove %s: %s", path, exc)


def swap(new: str, path: str, storage_options: dict[str, Any] | None = None) -> None:
    """Put the complete store ``new`` at ``path``; the old store is moved aside first and
    deleted only once the new one is in place (restored if the second move fails).

    POSIX has no portable atomic exchange of two folders: if the process is killed between
    the two renames (a window of microseconds locally), ``path`` is missing and both stores
    sit beside it, complete, as ``.NAME.hevr-old-…`` and ``.NAME.hevr-new-…`` (logged first);
    renaming either back restores a store. Nothing is lost either way. On an object store a
    move is a copy of every object and a delete (no rename exists there), so an overwrite
    copies the store twice; the same two steps keep the old store until the new one is in."""
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
        fs, root = filesystem(path, storage_options)
        fs_old, fs_new = filesystem(old, storage_options)[1], filesystem(new, storage_options)[1]
        _move_objects(fs, root, fs_old)
        try:
            _move_objects(fs, fs_new, root)
        except BaseException:
            _move_objects(fs, fs_old, root)
            raise
    remove_tree(old, storage_options)


def _move_objects(fs: Any, src: str, dst: str) -> None:
    """Move every object under ``src`` to the same key under ``dst``: copy all, then delete all
    (``fs.mv(recursive=True)`` would also try to copy S3's pseudo-folders, which are no objects)."""
    src, dst = src.rstrip("/"), dst.rstrip("/")
    fs.invalidate_cache(src)
    files = [f for f in fs.find(src) if f.startswith(src + "/")]
    if files:
        fs.copy(files, [dst + f[len(src):] for f in files])
        fs.rm(files)
    fs.invalidate_cache(src)
    fs.invalidate_cache(dst)
