"""The HTTP sessions of the object-storage filesystems that Zarr opens, closed before exit.

Zarr reads and writes a URL store through an *asynchronous* fsspec filesystem
(``zarr.storage.FsspecStore.from_url``: ``asynchronous=True``). s3fs, gcsfs and fsspec's HTTP
filesystem close the aiohttp session of a synchronous instance when it is collected, but not
that of an asynchronous one: at interpreter exit each left one line pair ``Unclosed client
session`` on stderr (12 after the test suite, some after every CLI command on ``s3://``).
:func:`track` records the filesystem of every store :func:`hevr.store.paths.zarr_store` makes;
:func:`close_sessions` closes their sessions on Zarr's event loop, where they were opened, and
runs once at exit (before Zarr stops that loop).
"""

from __future__ import annotations

import atexit
import contextlib
import threading
import weakref
from typing import Any

from zarr.core.sync import sync

__all__ = ["close_sessions", "track"]

_OPEN: weakref.WeakSet = weakref.WeakSet()
_LOCK = threading.Lock()
_REGISTERED = False
# where a filesystem keeps its session: s3fs's client context, fsspec HTTP's / gcsfs's aiohttp session
_SESSIONS = ("_s3creator", "_session")


def track(store: Any) -> Any:
    """Remember the asynchronous filesystem of a ``FsspecStore`` (returned unchanged)."""
    global _REGISTERED
    fs = getattr(store, "fs", None)
    fs = getattr(fs, "sync_fs", fs)  # zarr's wrapper around a filesystem without async support
    if fs is None:
        return store
    with _LOCK:
        with contextlib.suppress(TypeError):  # not weak-referenceable: nothing to close later
            _OPEN.add(fs)
        if not _REGISTERED:
            atexit.register(close_sessions)  # after zarr's own handler is registered: runs first
            _REGISTERED = True
    return store


def close_sessions() -> int:
    """Close the sessions of the tracked filesystems; returns how many were open.

    A session of an asynchronous filesystem belongs to Zarr's event loop, where it is closed
    (``await``); a filesystem closed here opens a new session when it is used again.

    >>> close_sessions()
    0
    """
    with _LOCK:
        open_now = list(_OPEN)
        _OPEN.clear()
    closed = 0
    for fs in open_now:
        for attr in _SESSIONS:
            session = fs.__dict__.get(attr)
            if session is None:
                continue
            with contextlib.suppress(Exception):  # at exit: a half torn-down loop or library
                _run(session.__aexit__(None, None, None) if attr == "_s3creator" else session.close())
                closed += 1
            with contextlib.suppress(AttributeError, TypeError):
                setattr(fs, attr, None)
                if attr == "_s3creator":
                    fs._s3 = None  # s3fs makes a new client on its next call
    return closed


def _run(coro: Any) -> None:
    """Await ``coro`` on Zarr's event loop (where the store's filesystem made its session)."""
    try:
        sync(coro, timeout=5)
    except BaseException:
        coro.close()  # never awaited: no "coroutine was never awaited" warning on top
        raise
