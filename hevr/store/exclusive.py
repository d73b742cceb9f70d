"""One writer per store: exclusive creation of local stores, the lock that marks a store being
written, serialised swaps, and the clean-up of what killed runs left beside a store.

Creating. A new local store is first built as a skeleton (its group, arrays and metadata,
marked incomplete) in a locked temporary sibling ``.NAME.hevr-tmp-TOKEN`` and then put at
``path`` by one rename that fails if ``path`` exists (Linux ``renameat2(RENAME_NOREPLACE)``;
where that is missing, an ``os.mkdir(path)`` claim, atomic on local disks and NFS, then a
rename onto that empty folder). Of several creators of one path exactly one wins; the others
get :class:`hevr.StoreExistsError` and leave nothing behind. ``path`` never exists without
its ``zarr.json``, and a store is marked complete only when its last brick is written.

Locking. The run that writes a local store holds an exclusive ``flock`` on the store's folder
(on the open folder, so the lock follows a rename) from creation to its return (the mark of
:func:`hevr.core.siblings.held_lock`): a second ``resume=True``, an ``overwrite=True`` that would swap
the store out, and the clean-up below see the lock and keep off. Swaps of stores in one
folder are serialised by a ``flock`` on the folder (:func:`swap_lock`). ``flock`` is advisory
and local: on filesystems without it (some network mounts) the locks are not taken (logged).

Clean-up. :func:`remove_leftovers` removes, before a run writes ``path``, the temporaries of
earlier runs whose writer is gone (no lock held): skeletons always; the new and old stores of
an interrupted overwrite only while ``path`` holds a complete store (when ``path`` is
missing they may be the only complete copies: they are named, never deleted).

>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> os.mkdir(os.path.join(d, "a")); rename_noreplace(os.path.join(d, "a"), os.path.join(d, "b"))
>>> os.mkdir(os.path.join(d, "c")); rename_noreplace(os.path.join(d, "c"), os.path.join(d, "b"))
Traceback (most recent call last):
...
FileExistsError: [Errno 17] File exists: ...
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import json
import logging
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path

from ..core.files import read_regular
from ..core.siblings import remove_if_abandoned, temp_sibling, temporaries
from ..errors import FileSystemError, StoreError, StoreExistsError

log = logging.getLogger(__name__)

__all__ = [
    "rename_noreplace",
    "StoreLock",
    "lock_store",
    "locked_folder",
    "swap_lock",
    "is_complete",
    "remove_leftovers",
    "remove_local_tree",
]

_AT_FDCWD = -100
_RENAME_NOREPLACE = 1
try:
    _RENAMEAT2 = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
except OSError:  # pragma: no cover - no C library to load
    _RENAMEAT2 = None
_NO_LOCKS = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EBADF, errno.EINVAL)


def rename_noreplace(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Rename the folder ``src`` to ``dst`` atomically, only if nothing is at ``dst``
    (``FileExistsError`` otherwise: ``os.rename`` would replace an empty folder)."""
    if _RENAMEAT2 is not None:
        if _RENAMEAT2(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), _RENAME_NOREPLACE) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):  # else: the filesystem lacks the flag
            raise OSError(err, os.strerror(err), os.fspath(dst))
    os.mkdir(dst)  # the claim: fails with EEXIST if anything is there
    try:
        os.rename(src, dst)  # onto our own empty folder
    except BaseException:
        with contextlib.suppress(OSError):
            os.rmdir(dst)
        raise


class StoreLock:
    """An exclusive ``flock`` held on a local store folder (module docstring); :meth:`release`
    (idempotent) or leave a ``with`` block to drop it."""

    def __init__(self, fd: int | None) -> None:
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> StoreLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _flock(fd: int, blocking: bool) -> bool:
    """Lock ``fd`` exclusively; False if another holder has it (non-blocking only); True also
    where the filesystem has no locks (logged once per call)."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        return True
    except BlockingIOError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LOCKS:
            raise
        log.warning("this filesystem has no flock (%s): concurrent writers of one store are not excluded", exc.strerror)
        return True


def lock_store(
    path: str | os.PathLike, *, name: str = "path", error: type[StoreError] = StoreExistsError, hold: bool = True
) -> StoreLock:
    """The lock of the local store folder ``path``, taken at once, or ``error`` (default
    :class:`hevr.StoreExistsError`) naming ``name`` when another run holds it (writes the store
    now). ``hold=False`` only checks (the lock is dropped at once)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_DIRECTORY", 0))
    except OSError as exc:
        raise FileSystemError(exc.errno, "locking the store", path, exc.strerror) from None
    lock = StoreLock(fd)
    try:
        free = _flock(fd, blocking=False)
    except BaseException:
        lock.release()
        raise
    if not free:
        lock.release()
        raise error(
            f"{name}: {path} is being written by another run right now (encrypt_volume, an overwrite or "
            "build_pyramid); wait for it to finish"
        )
    if not hold:
        lock.release()
    return lock


def locked_folder(path: str | os.PathLike, what: str) -> tuple[str, StoreLock]:
    """A new empty folder ``.NAME.hevr-WHAT-TOKEN`` beside ``path`` and its lock, held: a
    clean-up that found it unlocked in the instant after its ``mkdir`` holds the lock while it
    removes it, so the folder is checked to be still there once the lock is ours."""
    for _ in range(8):
        tmp = temp_sibling(path, what)
        os.mkdir(tmp)
        try:
            fd = os.open(tmp, os.O_RDONLY | os.O_CLOEXEC | getattr(os, "O_DIRECTORY", 0))
        except FileNotFoundError:
            continue  # removed already

        try:
            _flock(fd, blocking=True)
            with contextlib.suppress(OSError):
                if os.fstat(fd).st_nlink > 0 and os.path.samestat(os.fstat(fd), os.stat(tmp)):
                    return str(tmp), StoreLock(fd)
        except BaseException:  # the lock failed (or an interrupt): nothing of this folder is kept
            os.close(fd)
            with contextlib.suppress(OSError):
                os.rmdir(tmp)
            raise
        os.close(fd)
    raise FileSystemError(
        errno.EAGAIN,
        "creating a temporary folder beside",
        path,  # pragma: no cover
        "removed again and again by another process",
    )


@contextlib.contextmanager
def swap_lock(path: str | os.PathLike) -> Iterator[None]:
    """Serialise the swaps of stores in ``path``'s folder: an exclusive ``flock`` on the folder,
    waited for (a swap holds it for two renames and an open)."""
    parent = Path(path).parent
    try:
        fd = os.open(parent, os.O_RDONLY | os.O_CLOEXEC | getattr(os, "O_DIRECTORY", 0))
    except OSError as exc:
        raise FileSystemError(exc.errno, "locking the folder of", path, exc.strerror) from None
    try:
        _flock(fd, blocking=True)
        yield
    finally:
        os.close(fd)


def is_complete(path: str | os.PathLike) -> bool:
    """Whether the local ``path`` holds an hevr store marked complete (its ``zarr.json`` says so)."""
    try:  # read_regular: a FIFO in place of zarr.json must not block the clean-up
        doc = json.loads(read_regular(Path(path) / "zarr.json", "path", "a store document", limit=1 << 24))
        return doc["attributes"]["hevr"]["complete"] is True
    except (OSError, ValueError, KeyError, TypeError):
        return False


def remove_local_tree(path: str | os.PathLike, attempts: int = 6) -> bool:
    """``shutil.rmtree`` retried a few times ("Directory not empty" while a last write lands,
    entries vanishing under a concurrent clean-up); True once nothing is at ``path``."""
    for attempt in range(attempts):
        try:
            shutil.rmtree(path)
            return True
        except FileNotFoundError:
            if not os.path.lexists(path):
                return True
        except OSError as exc:
            if attempt == attempts - 1:
                log.warning("could not remove %s: %s", path, exc.strerror or exc)
                return False
        time.sleep(0.02 * (attempt + 1))
    return not os.path.lexists(path)


def remove_leftovers(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary folders of earlier runs beside the local store ``path`` whose
    writer is gone (module docstring); returns what was removed. Best effort (logged)."""
    kinds = ("tmp", "new", "old") if is_complete(path) else ("tmp",)
    removed = [
        t
        for t in temporaries(path, kinds)
        if t.is_dir() and not t.is_symlink() and remove_if_abandoned(t, remove_local_tree)
    ]
    for t in removed:
        log.info("removed %s, left beside %s by an earlier run that did not finish", t, path)
    return removed
