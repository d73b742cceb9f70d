"""Where stores live: local folders or fsspec URLs (replacing one store by another without ever
losing the old one, write beside, then swap, is :mod:`hevr.store.replacing`).

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

import hashlib
import inspect
import logging
import os
import secrets
from pathlib import Path
from typing import Any

from zarr.storage import FsspecStore

from ..core.files import (
    check_name,
    fs_errors,
    read_regular,
    write_checksummed,
)
from ..core.siblings import temporaries
from ..errors import (
    CorruptStoreError,
    ExistingFileError,
    MissingDependencyError,
    ParameterError,
)
from .metadata import sha256_tag
from .sessions import track

log = logging.getLogger(__name__)

__all__ = [
    "token",
    "is_local",
    "normalise",
    "store_exists",
    "interrupted_swaps",
    "read_document",
    "document_digest",
    "check_storage_options",
    "filesystem",
    "zarr_store",
    "check_reachable",
    "read_bytes",
    "object_sizes",
    "output_location",
    "write_new_bytes",
    "write_output",
]


def token() -> str:
    return secrets.token_hex(4)


def is_local(path: str) -> bool:
    return "://" not in path


def normalise(path: str | os.PathLike, name: str = "path") -> str:
    """The one spelling of a store path: local paths (and ``file://`` URLs) absolute and
    resolved (workers may run elsewhere), URLs without a trailing slash (``memory://x/`` and
    ``memory://x`` are one store). A text with ``://`` is a URL: its protocol must be one
    fsspec knows (``s3``, ``gs``, ``az``, ``memory``, chained ``simplecache::s3`` …), else a
    :class:`hevr.ParameterError` naming ``name`` — a local name may not contain ``://``
    (``dir/a://b.zarr`` or a typo such as ``s3a:/`` never becomes a local folder).

    >>> normalise("memory://bucket/v.zarr/")
    'memory://bucket/v.zarr'
    >>> normalise("file://" + str(Path("v.zarr").resolve())) == normalise("v.zarr")
    True
    >>> normalise("dir/a://b.zarr")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: path: expected a local path or an fsspec URL ..., got 'dir/a://b.zarr': ...
    """
    text = str(path)
    if text[:7].lower() == "file://":
        text = text[7:]
        if text.startswith("localhost/"):
            text = text[len("localhost") :]
    if is_local(text):
        check_name(text, name)  # a lone surrogate: a ParameterError, not a UnicodeEncodeError
        return str(Path(text).resolve())
    _check_protocol(text, name)
    return text.rstrip("/")


def _check_protocol(url: str, name: str) -> None:
    """Refuse a ``://`` text whose protocol fsspec does not know (:func:`normalise`)."""
    try:
        import fsspec
    except ImportError:  # the URL's reader says that fsspec is missing
        return
    known = set(fsspec.available_protocols())
    protocols = url.split("://", 1)[0].split("::")
    if not all(p in known for p in protocols):
        raise ParameterError(
            f"{name}: expected a local path or an fsspec URL (s3://, gs://, az://, memory://, "
            f"file://, …), got {url!r}: {protocols[-1]!r} is no protocol fsspec knows (a local "
            "name may not contain '://')"
        )


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
        raise ParameterError(
            f"storage_options: expected a dict of fsspec options with string keys or None, "
            f"got {type(storage_options).__name__}"
        )
    return dict(storage_options)


def filesystem(path: str, storage_options: dict[str, Any] | None = None) -> tuple[Any, str]:
    """The fsspec filesystem of the URL ``path`` (with ``storage_options``) and the path
    inside it."""
    try:
        import fsspec.core
    except ImportError:
        raise MissingDependencyError(
            f"path: {path} is a URL; reading it needs fsspec (pip install 'hevr[cloud]')"
        ) from None
    try:
        fs, root = fsspec.core.url_to_fs(path, **(storage_options or {}))
    except ImportError as exc:  # fsspec names the package of the protocol (s3fs, gcsfs, adlfs)
        raise MissingDependencyError(f"path: {path} needs a filesystem package that is not installed ({exc})") from None
    return fs, root


def zarr_store(path: str, storage_options: dict[str, Any] | None = None, *, read_only: bool = False) -> Any:
    """What ``zarr.open_group`` / ``zarr.open_array`` take as their store for ``path``: the
    local path itself, or a ``zarr.storage.FsspecStore`` of the URL with ``storage_options``."""
    if is_local(path):
        return path
    filesystem(path, storage_options)  # a clear error for a missing filesystem package
    store = FsspecStore.from_url(path, storage_options=dict(storage_options or {}), read_only=read_only)
    return track(store)  # its session closed before exit (hevr.store.sessions)


def check_reachable(path: str, client: Any) -> None:
    """Refuse a ``memory://`` store when the tasks run on a distributed cluster whose workers
    are other processes (module docstring); ``client`` is the active client or None."""
    if client is None or not path.lower().startswith("memory://"):
        return
    address = str(getattr(getattr(client, "scheduler", None), "address", "") or "")
    if address.startswith("inproc://"):  # the workers are threads of this process
        return
    raise ParameterError(
        f"path: {path}: memory:// stores live in this process; workers of a distributed "
        "cluster cannot see them — use a local path or an object store URL"
    )


def store_exists(path: str, storage_options: dict[str, Any] | None = None) -> bool:
    """Whether anything at all is at ``path`` (a folder, a file, or any object under a URL
    prefix): such a path is never written over without ``overwrite=True``."""
    if is_local(path):
        with fs_errors("looking for the store", path):
            return os.path.lexists(path) or _exists_strict(path)
    fs, root = filesystem(path, storage_options)
    fs.invalidate_cache(root)
    return bool(fs.exists(root))


def _exists_strict(path: str) -> bool:
    """False for a missing path; the ``OSError`` of anything else that stops a look (a name
    too long, a permission) is raised, where ``os.path.lexists`` says False."""
    try:
        os.lstat(path)
        return True
    except (FileNotFoundError, NotADirectoryError):
        return False


def interrupted_swaps(path: str) -> list[str]:
    """Stores an interrupted or failed overwrite left beside a local ``path``
    (:func:`hevr.store.replacing.swap`): its ``.NAME.hevr-old-TOKEN`` and ``.NAME.hevr-new-TOKEN``
    siblings (hevr.core.files naming; a name near the filesystem's limit has a hashed stem)."""
    if not is_local(path):
        return []
    return [str(q) for q in temporaries(path, ("old", "new"))]


def read_document(path: str, name: str, storage_options: dict[str, Any] | None = None) -> bytes:
    """The raw bytes of the Zarr metadata document ``name/zarr.json`` (``zarr.json`` for the
    group when ``name`` is empty) of the store at ``path``, local or fsspec."""
    rel = f"{name}/zarr.json" if name else "zarr.json"
    if is_local(path):  # never blocks: a FIFO in place of a document is refused
        return read_regular(Path(path) / rel, "path", f"the store document {rel}", error=CorruptStoreError)
    return read_bytes(f"{path.rstrip('/')}/{rel}", storage_options)


def document_digest(path: str, name: str, storage_options: dict[str, Any] | None = None) -> str:
    """``"sha256:<hex>"`` of a metadata document's exact bytes: every byte counts, since Zarr
    tolerates some damage (a misspelt key falls back to a default)."""
    return sha256_tag(read_document(path, name, storage_options))


def read_bytes(path: str, storage_options: dict[str, Any] | None = None) -> bytes:
    """The bytes of the file or object ``path`` (local, or a URL); ``FileNotFoundError`` if absent
    (a local path must be a regular file: :func:`hevr.core.files.read_regular`)."""
    if is_local(path):
        return read_regular(path, "path", "a file")
    fs, root = filesystem(path, storage_options)
    return fs.cat_file(root)


def object_sizes(path: str, storage_options: dict[str, Any] | None = None) -> dict[str, int]:
    """``{key relative to path: size in bytes}`` of every object under the URL ``path``, from
    one listing (``fs.find``: one LIST request per 1000 objects on S3)."""
    fs, root = filesystem(path, storage_options)
    root = root.rstrip("/")
    fs.invalidate_cache(root)  # a listing cached by this process may predate other writers
    found = fs.find(root, detail=True)
    return {k[len(root) + 1 :]: int(v.get("size") or 0) for k, v in found.items() if k.startswith(root + "/")}


def write_new_bytes(
    path: str, parts: Any, storage_options: dict[str, Any] | None = None, *, overwrite: bool = False, name: str = "path"
) -> None:
    """Write the concatenated ``parts`` to the object ``path`` in one request (an object store
    makes an object visible whole or not at all), refusing an existing object with
    :class:`hevr.ExistingFileError` naming ``name`` unless ``overwrite``.

    What is guaranteed without ``overwrite``: an object that exists before the call is never
    replaced. Whether two writers racing for a new name can both succeed depends on the store:
    the write is a conditional create (fsspec's ``pipe_file(mode="create")``) — atomic on AWS S3
    and S3 servers that honour ``If-None-Match: *`` (s3fs), and on fsspec's ``memory://``; a
    filesystem without it (or an fsspec older than that mode) gets a check just before the one
    request, and a writer that creates the object inside that window is replaced."""
    fs, root = filesystem(path, storage_options)
    data = b"".join(parts)
    if overwrite:
        fs.pipe_file(root, data)
        return
    fs.invalidate_cache(root)
    if fs.exists(root):
        raise ExistingFileError(name, path)
    try:
        if "mode" in inspect.signature(fs.pipe_file).parameters:
            fs.pipe_file(root, data, mode="create")
        else:  # pragma: no cover - fsspec before the "create" mode
            fs.pipe_file(root, data)
    except FileExistsError:
        raise ExistingFileError(name, path) from None


def output_location(path: Any, name: str = "path") -> Path | str:
    """Where a file is to be written: a local file (``Path``; ``file://`` URLs included) or an
    fsspec URL (``str``; a text with ``://`` whose protocol fsspec does not know is a
    :class:`hevr.ParameterError` naming ``name``, :func:`normalise`)."""
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ParameterError(f"{name}: expected a file path or an fsspec URL, got {path!r}")
    if "://" not in str(path):
        return Path(path)
    where = normalise(path, name)
    return Path(where) if is_local(where) else where


def write_output(
    where: Path | str,
    parts: list[Any],
    storage_options: dict[str, Any] | None = None,
    *,
    overwrite: bool = False,
    name: str = "path",
    doing: str = "writing",
) -> int:
    """Write ``parts`` and the SHA-256 of all of them (the trailer of ``.hevr`` and ``.hevrsums``
    files) to ``where`` (:func:`output_location`): a local file through
    :func:`hevr.core.files.write_checksummed`, an object in one request (:func:`write_new_bytes`);
    an existing one only with ``overwrite``. Returns the bytes written."""
    if isinstance(where, Path):
        write_checksummed(where, parts, overwrite=overwrite, name=name, doing=doing)
        return where.stat().st_size
    digest = hashlib.sha256()
    for part in parts:
        digest.update(part)
    parts = [*parts, digest.digest()]
    write_new_bytes(where, parts, storage_options, overwrite=overwrite, name=name)
    return sum(memoryview(p).nbytes for p in parts)
