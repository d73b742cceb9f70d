"""One file a running ``hevr serve`` looks at again and again (:class:`FileWatch`): the tokens
file (:mod:`hevr.serve.token_file`) and each served store's ``zarr.json``
(:mod:`hevr.serve.store_watch`).

A look is a ``stat``, at most once per :data:`CHECK_SECONDS` (unless asked sooner); the file
changed when its stat key (device, inode, size, modification time; :func:`stat_key`) differs
from the key of the version in force. A version that could not be used is remembered
(:meth:`FileWatch.fail`), so it is reported once and tried again only once the file changes
again.

>>> import tempfile, os
>>> path = os.path.join(tempfile.mkdtemp(), "f")
>>> open(path, "w").close()
>>> t = [0.0]
>>> w = FileWatch(path, clock=lambda: t[0])
>>> w.look() is None                    # unchanged (and not yet due)
True
>>> with open(path, "w") as fh: n = fh.write("new")
>>> t[0] += 1.5
>>> key = w.look(); key is not None and key != w.key
True
>>> w.fail(key), w.fail(key), w.look(force=True) == key
(True, False, True)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

__all__ = ["CHECK_SECONDS", "FileWatch", "stat_key"]

CHECK_SECONDS = 1.0  # a watched file is stat'ed at most this often (on a request)


def stat_key(path: str | os.PathLike) -> tuple:
    """``(st_dev, st_ino, st_size, st_mtime_ns)`` of ``path`` (symbolic links followed), or
    ``("missing", errno)`` when it cannot be ``stat``\\ ed.

    >>> stat_key("no/such/file")[0]
    'missing'
    """
    try:
        st = os.stat(path)
    except OSError as exc:
        return ("missing", exc.errno)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def is_missing(key: tuple) -> bool:
    """Whether a :func:`stat_key` says the file could not be ``stat``\\ ed.

    >>> is_missing(("missing", 2)), is_missing((1, 2, 3, 4))
    (True, False)
    """
    return key[0] == "missing"


class FileWatch:
    """When to look at ``path`` again and whether it changed (the module docstring).

    Parameters
    ----------
    path : str or Path
        The watched file.
    interval : float
        Seconds between two looks (default :data:`CHECK_SECONDS`).
    clock : callable
        The monotonic clock (tests pass their own).
    key : tuple, optional
        The stat key of the version in force (default: the file's now).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        interval: float = CHECK_SECONDS,
        clock: Callable[[], float] = time.monotonic,
        key: tuple[Any, ...] | None = None,
    ) -> None:
        self.path = path
        self.interval = float(interval)
        self.clock = clock
        self.key: tuple[Any, ...] = stat_key(path) if key is None else key
        self.failed: tuple | None = None
        self.checked = clock()

    def soon(self) -> None:
        """Look at the next :meth:`look`, whenever it comes."""
        self.checked = float("-inf")

    def look(self, force: bool = False) -> tuple | None:
        """The file's stat key if it is time to look (``force``: now) and the file is neither the
        version in force nor the one that failed last (``force``: whatever it is); else None."""
        now = self.clock()
        if not force and now - self.checked < self.interval:
            return None
        self.checked = now
        key = stat_key(self.path)
        if not force and (key == self.key or key == self.failed):
            return None
        return key

    def accept(self, key: tuple) -> None:
        """The version of stat key ``key`` is in force from now on."""
        self.key, self.failed = key, None

    def fail(self, key: tuple) -> bool:
        """The version of stat key ``key`` could not be used; whether this is news (report it)."""
        news = key != self.failed
        self.failed = key
        return news
