"""Temporary siblings: the files and folders hevr writes beside a target before it moves them into
place, named ``.STEM.hevr-WHAT-TOKEN`` (``WHAT``: tmp, new, old) in the target's folder.

A writer holds an exclusive ``flock`` on its temporary while it works (:func:`held_lock`), so
:func:`remove_stale` can tell one left by a killed writer (no lock held: removed by the next
write to the same path) from one that is being written right now (locked: left alone). A name
so long that the temporary's would exceed the filesystem's limit gets a short hashed stem
(:func:`sibling_stem`), so a path near the limit stays writable.

>>> t = temp_sibling("folder/v.zarr", "tmp")
>>> t.name.startswith(".v.zarr.hevr-tmp-"), is_temporary(t, "folder/v.zarr")
(True, True)
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
import secrets
import shutil
import stat
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

log = logging.getLogger(__name__)

__all__ = [
    "NAME_MAX",
    "held_lock",
    "is_temporary",
    "remove_if_abandoned",
    "remove_stale",
    "sibling_stem",
    "temp_sibling",
    "temporaries",
]

#: The longest file name written beside a target: NAME_MAX of every common filesystem is 255.
NAME_MAX = 255
_TOKEN_CHARS = 8  # secrets.token_hex(4)
_SUFFIX = ".hevr-"  # .STEM.hevr-WHAT-TOKEN


def sibling_stem(name: str, room: int = len(_SUFFIX) + 4 + 1 + _TOKEN_CHARS + 1) -> str:
    """The stem of a temporary sibling's name ``.STEM.hevr-WHAT-TOKEN``: ``name`` itself, or a
    short hash of it when the sibling's name would not fit in :data:`NAME_MAX` bytes.

    >>> sibling_stem("v.zarr")
    'v.zarr'
    >>> len(sibling_stem("x" * 250)) <= 200
    True
    """
    raw = os.fsencode(name)  # the bytes on disk: a name that is not UTF-8 (surrogate escapes) too
    if len(raw) + room <= NAME_MAX:
        return name
    return raw[:40].decode(errors="ignore") + "~" + hashlib.sha256(raw).hexdigest()[:16]


def temp_sibling(path: str | os.PathLike, what: str) -> Path:
    """A fresh path ``.STEM.hevr-WHAT-TOKEN`` beside ``path`` (``what``: tmp, new, old)."""
    p = Path(path)
    return p.with_name(f".{sibling_stem(p.name)}{_SUFFIX}{what}-{secrets.token_hex(_TOKEN_CHARS // 2)}")


def is_temporary(path: str | os.PathLike, of: str | os.PathLike, kinds: Iterable[str] = ("tmp", "new", "old")) -> bool:
    """Whether ``path`` is a temporary sibling (:func:`temp_sibling`) of ``of``, of one of ``kinds``."""
    p, o = Path(path), Path(of)
    head = f".{sibling_stem(o.name)}{_SUFFIX}"
    if p.parent != o.parent or not p.name.startswith(head):
        return False
    what, _, tok = p.name[len(head) :].rpartition("-")
    return what in tuple(kinds) and len(tok) == _TOKEN_CHARS


def temporaries(path: str | os.PathLike, kinds: Iterable[str] = ("tmp", "new", "old")) -> list[Path]:
    """The temporary siblings of ``path`` that exist now (sorted)."""
    p = Path(path)
    try:
        names = os.listdir(p.parent if str(p.parent) else ".")
    except OSError:
        return []
    kinds = tuple(kinds)
    return sorted(p.with_name(n) for n in names if is_temporary(p.with_name(n), p, kinds))


@contextlib.contextmanager
def held_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive ``flock`` on the file or folder ``path`` while the block runs: the mark
    of a temporary that its writer is still working on (:func:`remove_stale`)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def remove_if_abandoned(path: Path, remove: Callable[[Path], bool] | None = None) -> bool:
    """Remove the temporary ``path`` if nobody holds its lock (its writer is gone), holding the
    lock while it is removed (with ``remove``, default: unlink, or rmtree for a folder): a
    writer that created it a moment ago and waits for its lock then finds it unlinked and
    starts afresh (:func:`write_file`, :func:`hevr.store.exclusive.locked_folder`). False if
    it was left (held, or it could not be removed: logged)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False  # held: its writer is alive (or the filesystem cannot tell: leave it)
        if remove is not None:
            return remove(path)
        try:
            if stat.S_ISDIR(os.fstat(fd).st_mode):
                shutil.rmtree(path)
            else:
                path.unlink()
        except OSError as exc:
            log.warning("could not remove %s (left by an earlier run): %s", path, exc.strerror)
            return False
        return True
    finally:
        os.close(fd)


def remove_stale(path: str | os.PathLike, kinds: Iterable[str] = ("tmp",)) -> list[Path]:
    """Remove the temporary siblings of ``path`` (of ``kinds``) whose writer is gone (no lock
    held on them: a killed or failed earlier run); returns what was removed. Best effort: one
    that cannot be removed is logged and left."""
    removed = []
    for t in temporaries(path, kinds):
        if remove_if_abandoned(t):
            removed.append(t)
            log.info("removed %s, left beside %s by an earlier run that did not finish", t, path)
    return removed
