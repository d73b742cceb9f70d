"""Small file helpers: the one way hevr writes a file (atomically, never over an existing one
unless asked), reads one (regular files only: a FIFO or a device would block), reports a
missing path, and turns the operating system's refusals into :class:`hevr.FileSystemError`.

Writing. :func:`write_file` writes through a temporary sibling ``.NAME.hevr-tmp-<token>`` in
the same folder and then either ``os.replace`` (``overwrite=True``) or ``os.link`` (otherwise:
the link fails atomically if ``path`` exists, so there is no window between a check and the
write). The writer holds an exclusive ``flock`` on its temporary file while it writes, so
:func:`~hevr.core.siblings.remove_stale` can tell a temporary left by a killed writer (no lock
held: removed by the next write to the same path) from one that is being written right now
(locked: left alone); the temporaries' names, locks and removal are :mod:`hevr.core.siblings`'.

Reading. :func:`read_regular` opens with ``O_NONBLOCK`` (which makes opening a FIFO return at
once) and checks ``fstat`` before reading a byte; :func:`check_regular` does the same check with
``stat`` for files another library opens (Zarr chunks and documents).

>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> write_atomic(os.path.join(d, "a.json"), "{}\\n", mode=0o600)
>>> oct(os.stat(os.path.join(d, "a.json")).st_mode & 0o777)
'0o600'
>>> read_regular(os.path.join(d, "a.json"), "path", "a JSON file")
b'{}\\n'
>>> require_file(os.path.join(d, "missing.json"), "key", "a key file")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
hevr.errors.MissingFileError: key: expected a key file, found nothing at .../missing.json
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import logging
import os
import shutil
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from ..errors import (
    ExistingFileError,
    FileSystemError,
    HevrError,
    MissingFileError,
    NotRegularFileError,
    ParameterError,
)
from .siblings import remove_stale, temp_sibling

log = logging.getLogger(__name__)

__all__ = [
    "check_name",
    "require_file",
    "write_atomic",
    "write_checksummed",
    "write_file",
    "read_regular",
    "check_regular",
    "file_kind",
    "fs_errors",
    "os_error",
]


def file_kind(mode: int) -> str:
    """What a ``st_mode`` is, in words.

    >>> file_kind(stat.S_IFIFO), file_kind(stat.S_IFREG)
    ('a FIFO', 'a regular file')
    """
    for test, words in (
        (stat.S_ISREG, "a regular file"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
    ):
        if test(mode):
            return words
    return "not a regular file"


def os_error(exc: OSError, doing: str, path: str | os.PathLike) -> HevrError:
    """The hevr error for an ``OSError`` met while ``doing`` something to ``path``: missing ->
    :class:`MissingFileError`, exists -> :class:`ExistingFileError`, anything else ->
    :class:`FileSystemError` with the same errno; hevr errors pass through unchanged."""
    if isinstance(exc, HevrError):
        return exc
    where = exc.filename or path
    if exc.errno == errno.ENOENT:
        return MissingFileError("path", "an existing file or folder", where)
    if exc.errno == errno.EEXIST:
        return ExistingFileError("path", where)
    return FileSystemError(exc.errno, doing, where, exc.strerror)


@contextlib.contextmanager
def fs_errors(doing: str, path: str | os.PathLike) -> Iterator[None]:
    """Turn an ``OSError`` (not already an hevr error) raised inside the block into
    :class:`FileSystemError` (``doing`` names the operation, e.g. ``"writing the image"``)."""
    try:
        yield
    except HevrError:
        raise
    except OSError as exc:
        raise FileSystemError(exc.errno, doing, exc.filename or path, exc.strerror) from exc


def check_name(path: str | os.PathLike, name: str) -> None:
    """Refuse a path no filesystem can store — a ``str`` with a lone surrogate that is not one
    of :func:`os.fsdecode`'s escapes — with a :class:`hevr.ParameterError` naming ``name`` and
    the path's ``repr``. Names that are not UTF-8 but came from the OS (argv, ``os.listdir``,
    ``os.fsdecode(b"\\xff.hevr")``) encode back to their bytes and pass.

    >>> check_name(os.fsdecode(b"\\xff.hevr"), "path")
    >>> check_name(chr(0xD800) + ".hevr", "path")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: path: expected a name the filesystem can store (...), got '\\ud800.hevr'
    """
    try:
        os.fsencode(path)
    except UnicodeEncodeError:
        raise ParameterError(
            f"{name}: expected a name the filesystem can store (UTF-8, or bytes decoded with "
            f"os.fsdecode), got {os.fspath(path)!r}"
        ) from None


def write_file(
    path: str | os.PathLike,
    parts: Iterable[Any],
    *,
    mode: int = 0o644,
    overwrite: bool = False,
    name: str = "path",
    doing: str = "writing",
    checksum: bool = False,
) -> None:
    """Write the bytes-like ``parts`` to ``path`` atomically: through a locked temporary sibling,
    then ``os.replace`` (``overwrite=True``) or an exclusive link (otherwise; an existing
    ``path`` raises :class:`hevr.ExistingFileError` naming ``name``, and is never touched). The
    file never exists half-written, nor with a mode other than ``mode``. With ``checksum`` the
    SHA-256 of all parts is appended (the trailer of ``.hevr`` and ``.hevrsums`` files). An
    ``OSError`` (disk full, read-only filesystem, …) becomes :class:`hevr.FileSystemError`
    naming ``doing`` and ``path``; the temporary is removed, and one left by a killed earlier
    writer of the same path is removed too."""
    check_name(path, name)
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    require_file(folder, name, "an existing folder", directory=True)
    remove_stale(path)
    with fs_errors(doing, path):  # a name too long for the filesystem fails here already
        there = not overwrite and (path.exists() or path.is_symlink())
    if there:  # fail fast; the link below decides
        raise ExistingFileError(name, path)
    digest = hashlib.sha256() if checksum else None
    with fs_errors(doing, path):
        tmp, fd = _locked_temporary(path)
        try:
            try:
                os.fchmod(fd, mode)
                for part in parts:
                    view = memoryview(part).cast("B")
                    if digest is not None:
                        digest.update(view)
                    _write_all(fd, view)
                if digest is not None:
                    _write_all(fd, memoryview(digest.digest()))
                if overwrite:  # still locked: a clean-up of another writer keeps off until it is in place
                    os.replace(tmp, path)
                else:
                    _link_new(tmp, path, name)
            finally:
                os.close(fd)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise


def _locked_temporary(path: Path) -> tuple[Path, int]:
    """A new temporary sibling of ``path`` (mode 0600), open for writing and locked. A clean-up
    (:func:`~hevr.core.siblings.remove_stale`) of another writer of ``path`` may find it in the instant between
    its creation and the lock and remove it: then the lock is taken on an unlinked file, which
    is seen (no links) and a fresh temporary is made."""
    for _ in range(8):
        tmp = temp_sibling(path, "tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if os.fstat(fd).st_nlink > 0:
                return tmp, fd
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        os.close(fd)
    raise OSError(
        errno.EAGAIN,
        "a temporary file was removed again and again by another process",  # pragma: no cover
        str(path),
    )


def _write_all(fd: int, view: memoryview) -> None:
    while view:
        n = os.write(fd, view)
        view = view[n:]


def write_atomic(
    path: str | os.PathLike,
    text: str,
    mode: int = 0o644,
    *,
    overwrite: bool = True,
    name: str = "path",
    doing: str = "writing",
) -> None:
    """Write ``text`` (UTF-8) to ``path`` with :func:`write_file` (``overwrite=True`` by default
    here: journals; key files pass ``overwrite`` through)."""
    write_file(path, [text.encode()], mode=mode, overwrite=overwrite, name=name, doing=doing)


def write_checksummed(
    path: str | os.PathLike,
    parts: Iterable[Any],
    *,
    overwrite: bool = False,
    name: str = "path",
    doing: str = "writing",
) -> None:
    """Write ``parts`` and then the SHA-256 of all of them to ``path`` with :func:`write_file`:
    the layout of ``.hevr`` images and ``.hevrsums`` files, whose readers check the trailer
    before anything else. An existing ``path`` is replaced only with ``overwrite=True``."""
    write_file(path, parts, overwrite=overwrite, name=name, doing=doing, checksum=True)


def _link_new(tmp: Path, path: Path, name: str) -> None:
    """Put ``tmp`` at ``path`` only if nothing is there, atomically; then drop ``tmp``."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise ExistingFileError(name, path) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK, errno.ENOSYS):
            raise
        # a filesystem without hard links: exclusive create, then copy
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, os.stat(tmp).st_mode & 0o777)
        except FileExistsError:
            raise ExistingFileError(name, path) from None
        with os.fdopen(fd, "wb") as out, open(tmp, "rb") as src:
            shutil.copyfileobj(src, out)
    os.unlink(tmp)


def require_file(path: str | os.PathLike, name: str, expected: str, *, directory: bool = False) -> Path:
    """Return ``Path(path)`` if it exists (as a folder when ``directory``), else raise
    :class:`hevr.MissingFileError` naming the parameter ``name`` and what was ``expected``."""
    p = Path(path)
    try:
        found = p.is_dir() if directory else p.exists()
    except (OSError, ValueError):  # a name the OS refuses (too long, NUL byte) names nothing
        found = False
    if not found:
        raise MissingFileError(name, expected, p)
    return p


def check_regular(path: str | os.PathLike, name: str, expected: str, *, error: Any = None) -> os.stat_result:
    """``stat`` of ``path`` if it is a regular file (never opens it: a FIFO would block);
    :class:`MissingFileError` if absent, :class:`NotRegularFileError` (or ``error(message)``
    when given, e.g. ``CorruptStoreError`` for a chunk inside a store) for anything else."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise MissingFileError(name, expected, path) from None
    except (OSError, ValueError) as exc:
        if isinstance(exc, OSError) and exc.errno == errno.ENOTDIR:
            raise MissingFileError(name, expected, path) from None
        raise FileSystemError(
            getattr(exc, "errno", None), f"reading {expected}", path, getattr(exc, "strerror", None) or str(exc)
        ) from None
    if not stat.S_ISREG(st.st_mode):
        refused = NotRegularFileError(name, expected, path, file_kind(st.st_mode))
        raise (error(str(refused)) if error is not None else refused)
    return st


def read_regular(
    path: str | os.PathLike, name: str, expected: str, *, limit: int | None = None, error: Any = None
) -> bytes:
    """The bytes of the regular file ``path``, refusing anything else before reading a byte
    (:func:`check_regular`'s errors, checked on the opened file with ``fstat``); ``limit``
    bounds the size (a :class:`hevr.ParameterError` beyond it, before reading)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise MissingFileError(name, expected, path) from None
    except OSError as exc:
        if exc.errno == errno.ENOTDIR:
            raise MissingFileError(name, expected, path) from None
        if exc.errno in (errno.ENXIO, errno.EOPNOTSUPP):  # a socket cannot be opened: say what is there
            check_regular(path, name, expected, error=error)
        raise FileSystemError(exc.errno, f"reading {expected}", path, exc.strerror) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            err = NotRegularFileError(name, expected, path, file_kind(st.st_mode))
            raise (error(str(err)) if error is not None else err)
        if limit is not None and st.st_size > limit:
            raise ParameterError(
                f"{name}: expected {expected} of at most {limit} bytes, got {st.st_size} bytes at {path}"
            )
        os.set_blocking(fd, True)
        with fs_errors(f"reading {expected}", path), os.fdopen(os.dup(fd), "rb") as fh:
            return fh.read()
    finally:
        os.close(fd)
