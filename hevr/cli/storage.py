"""Stores, frames and ray sums on object storage, on the command line.

Every command that reads or writes a store, a ``.hevr`` frame or a ``.hevrsums`` file takes an
fsspec URL where it takes a path (``s3://bucket/vol.zarr``, ``gs://…``, ``az://…``; ``file://``
is the local path) and the filesystem's options as ``--storage-option KEY=VALUE`` (repeatable).
A VALUE is read as JSON where it parses (``anon=true``, ``client_kwargs={"region_name":
"eu-west-1"}``), else taken as a string (``endpoint_url=http://127.0.0.1:9000``). The environment
variable ``HEVR_STORAGE_OPTIONS`` may hold a JSON object of options too (so that credentials
need not appear in a command line); ``--storage-option`` overrides its keys. Options are
passed to hevr and on to the workers; they are never printed (nor echoed in an error).

Output files (frames, sums, ``hevr decrypt``'s PNG and ``--npy``) are never written over an
existing file or object unless ``--force``: :func:`output_file` refuses one before any work
(exit 2), and the write itself refuses it again, atomically.

The option's type and group are in :mod:`hevr.cli.options` (the parser builds them without
this module).

>>> is_url("s3://b/v.zarr"), is_url("file:///tmp/v.zarr"), is_url("v.zarr")
(True, False, False)
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import check_regular, write_file
from ..errors import ExistingFileError, MissingFileError
from ..image.display import save_png
from ..image.header import MAGIC
from ..rendering.pipeline.sums_file import MAGIC as SUMS_MAGIC
from ..store.paths import (
    normalise,
    object_sizes,
    read_bytes,
    read_document,
    store_exists,
)
from ..store.reader import EncryptedVolume, open_volume
from .options import STORAGE_OPTIONS_ENV
from .util import (
    UsageError,
    check_new_file,
    check_store_path,
    check_writable_dir,
    disk_usage,
)

__all__ = [
    "storage_options",
    "is_url",
    "local_path",
    "open_store",
    "output_file",
    "save_frame",
    "save_decrypted",
    "size_of",
    "head_of",
    "png_name",
    "url_kind",
    "encrypt_target",
]


def storage_options(args: Any) -> dict | None:
    """The options of this command: ``$HEVR_STORAGE_OPTIONS``, then ``--storage-option`` (None if none)."""
    out: dict[str, Any] = {}
    env = os.environ.get(STORAGE_OPTIONS_ENV, "").strip()
    if env:
        try:
            doc = json.loads(env)
        except ValueError:
            doc = None
        if not isinstance(doc, dict):
            raise UsageError(
                f"{STORAGE_OPTIONS_ENV}: expected a JSON object of fsspec options, got something "
                "else (its value is not shown)"
            )
        out.update(doc)
    out.update(dict(getattr(args, "storage_option", None) or []))
    return out or None


def is_url(text: Any) -> bool:
    """Whether a command-line path is a URL of a remote filesystem (``file://`` is local)."""
    text = str(text)
    return "://" in text and text[:7].lower() != "file://"


def local_path(text: Any) -> Path:
    """A local command-line path (``file://`` stripped, ``~`` expanded)."""
    text = str(text)
    return Path(normalise(text)) if text[:7].lower() == "file://" else Path(text).expanduser()


def open_store(text: str, word: str = "STORE", so: dict | None = None) -> EncryptedVolume:
    """Open the store the command line names (a folder checked as one first, or a URL)."""
    if is_url(text):
        return open_volume(text, storage_options=so)
    return open_volume(check_store_path(local_path(text), word).absolute())


def output_file(
    text: str, option: str = "--out", suffix: str | None = None, *, force: bool = False, so: dict | None = None
) -> Path | str:
    """Where a frame or sums file goes: a checked local path, or a URL (written in one request).
    A file (or object) already there is refused here, before any work, unless ``force``
    (:class:`hevr.ExistingFileError` naming ``option``; exit 2, the message says ``--force``);
    the write refuses it again, atomically (:func:`save_frame`)."""
    if is_url(text):
        url = normalise(text, option)
        if not force and store_exists(url, so):
            raise ExistingFileError(option, text)
        return url
    path = local_path(text)
    check_new_file(path, option, suffix, force=force)
    return path


def save_frame(
    img: Any,
    out: Path | str,
    option: str = "--out",
    *,
    force: bool = False,
    so: dict | None = None,
    private_key: Any = None,
) -> None:
    """``img.save(out)``, replacing a file there only with ``force``; an existing file is
    reported as ``option``'s (it may have appeared while the frame was rendered). With the
    ``private_key`` a verified frame is checked and stamped (:meth:`hevr.EncryptedImage.save`)."""
    try:
        img.save(out, overwrite=force, storage_options=so, private_key=private_key)
    except ExistingFileError:
        raise ExistingFileError(option, out) from None


def save_decrypted(
    arr: Any, out: Path, npy: Path | None, window: Any, *, force: bool = False, plane: Any = None, hits: Any = None
) -> None:
    """``hevr decrypt``'s PNG and (``--npy``) float64 values, each written atomically and over an
    existing file only with ``force``; one that appeared meanwhile is reported as its option's.
    A slice's PNG (``plane``: its plane) is turned for display (:func:`hevr.image.orient.orient_slice`);
    the ``--npy`` values keep the plane's pixel order (that of :func:`hevr.render_slice_plain`)."""
    try:
        save_png(arr, out, window=window, overwrite=force, plane=plane, hits=hits)
    except ExistingFileError:
        raise ExistingFileError("--out", out) from None
    if npy is not None:
        buf = io.BytesIO()
        np.save(buf, arr)
        write_file(npy, [buf.getbuffer()], overwrite=force, name="--npy", doing="writing the pixel values")


def size_of(path: Any, so: dict | None = None) -> int:
    """Bytes of a local file or folder, or of every object under a URL."""
    if not is_url(path):
        return disk_usage(local_path(path))
    if not store_exists(normalise(str(path)), so):
        return 0
    sizes = object_sizes(normalise(str(path)), so)
    if sizes:
        return sum(sizes.values())
    return len(read_bytes(normalise(str(path)), so))


def head_of(text: str, n: int, word: str, what: str, so: dict | None = None) -> bytes:
    """The first ``n`` bytes of the file or object the command line names (MissingFileError if absent)."""
    if is_url(text):
        try:
            return read_bytes(normalise(text), so)[:n]
        except FileNotFoundError:
            raise MissingFileError(word, what, text) from None
    check_regular(local_path(text), word, what)  # a FIFO or a device would block the read
    with open(local_path(text), "rb") as fh:
        return fh.read(n)


def png_name(out: Path | str) -> str:
    """The PNG name to suggest for a frame: beside a local one, the frame's name for a URL."""
    if isinstance(out, Path):
        return str(out.with_suffix(".png"))
    return Path(str(out).rsplit("/", 1)[-1]).with_suffix(".png").name


def url_kind(url: str, so: dict | None = None) -> str:
    """What ``hevr info URL`` describes: ``"store"`` (a zarr.json under it), else ``"frame"`` or
    ``"sums"`` by the object's magic; anything else is a usage error naming the URL."""
    what = "a store, frame or sums file"
    if not store_exists(url, so):
        raise MissingFileError("PATH", what, url)
    try:
        read_document(url, "", so)
        return "store"
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        pass
    head = head_of(url, len(MAGIC), "PATH", what, so)
    if head[:-1] == MAGIC[:-1]:
        return "frame"
    if head == SUMS_MAGIC[: len(MAGIC)]:
        return "sums"
    raise UsageError(f"PATH: expected {what}, got an object that is none of them ({url})")


def encrypt_target(args: Any, so: dict | None) -> Path | str:
    """``hevr encrypt --out STORE``: a folder (in a writable folder) or a URL; one that exists
    only with ``--resume`` or ``--overwrite``; ``--resume`` only of one that exists."""
    local = None if is_url(args.out) else local_path(args.out).absolute()
    exists = store_exists(normalise(args.out), so) if local is None else local.exists()
    if exists and local is not None and not local.is_dir():
        raise UsageError(f"--out: expected a store folder (e.g. vol.zarr), got a file ({args.out})")
    if exists and not (args.resume or args.overwrite):
        raise UsageError(
            f"--out: {args.out} exists; pass --overwrite to replace it or --resume to finish an interrupted run"
        )
    if not exists and args.resume:
        raise MissingFileError("--resume", "the interrupted store named by --out", args.out)
    if local is None:
        return normalise(args.out)
    check_writable_dir(local)
    return local
