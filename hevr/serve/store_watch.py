"""A store rewritten under a running ``hevr serve`` is noticed and opened again
(:class:`StoreWatch`).

The owner re-encrypts a served store in place (``hevr encrypt --overwrite``: a new store id), or
adds pyramid levels to it (``hevr pyramid``: the same id, new metadata). The handle the server
opened still holds the old metadata and digests, so every brick it reads from the new store fails
its digest check ("corrupted, truncated, swapped with another brick or copied from another
store"). Before a request names a store, the server ``stat``\\ s that store's ``zarr.json`` (the
root document that holds its metadata), at most once a second per store
(:class:`~hevr.serve.file_watch.FileWatch`); when its inode, size or modification time changed,
the store is opened again (:func:`hevr.open_volume`) and served under the same name: its new id
from then on, the old id no longer (a token lists ids: give it the new one). A store resident on
the workers (``hevr serve --persist``) is made resident again.

Opening it again runs on a thread of its own, one at a time per store, never on the server's
event loop (loading every brick onto the workers can take minutes: the other requests, the
connection deadlines and ``/v1/health`` go on meanwhile). Until it is done, a request naming that
store is answered 503 with ``Retry-After`` ("store being reopened"): the old handle reads bricks
that are no longer there, and the old resident copy, though consistent with the old metadata, is
what the owner replaced (re-encryption is how a store is withdrawn). The listing keeps the store
under its old id until then. A new version that cannot be opened yet (still being written) is
logged, and the old handle stays until the file changes again. A new version that opens but cannot
be made resident (the workers' memory, a worker lost) is tried again after 5 s, 10 s, ... at most
:data:`RETRY_MAX` s apart, the store answered 503 meanwhile (its old resident copy is what the
owner replaced; the file will not change again to say so). A brick that fails its check has
every store looked at by the next request (:meth:`StoreWatch.soon`), so a render that came within
the second after a rewrite costs one failed request at most.

Only stores on a local (or mounted) filesystem are watched; a store behind a URL (``s3://``, ...)
is served as opened: restart ``hevr serve`` after re-encrypting it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

from ..errors import HevrError
from ..store.reader import open_volume
from .file_watch import CHECK_SECONDS, FileWatch, is_missing

log = logging.getLogger("hevr.serve")

__all__ = ["CHECK_SECONDS", "RETRY_AFTER", "StoreWatch"]

RETRY_AFTER = 2  # seconds a client is asked to wait for a store being opened again
RETRY_FIRST, RETRY_MAX = 5.0, 300.0  # seconds before a failed persist of a new version is tried again


class _PersistFailed(Exception):
    """A new version opened but not made resident: tried again after a while (module docstring)."""


def _watched(path: str) -> str | None:
    """The ``zarr.json`` of a local store (None: a store behind a URL, not watched).

    >>> _watched("s3://bucket/ct.zarr") is None, _watched("ct.zarr")
    (True, 'ct.zarr/zarr.json')
    """
    return None if "://" in str(path) else os.path.join(path, "zarr.json")


class StoreWatch:
    """The served local stores' ``zarr.json`` watched, and the stores being opened again.

    Parameters
    ----------
    stores : dict
        Store id -> opened store, as served now.
    interval : float
        Seconds between two looks at one store (default :data:`CHECK_SECONDS`).
    clock : callable
        The monotonic clock (tests pass their own).
    """

    def __init__(
        self, stores: dict, *, interval: float = CHECK_SECONDS, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.interval, self.clock = float(interval), clock
        self._files = {
            sid: FileWatch(f, interval=interval, clock=clock)
            for sid, ev in stores.items()
            if (f := _watched(ev.path)) is not None
        }
        self._lock = threading.Lock()
        self._reopening: dict[str, tuple] = {}  # store id -> the stat key of the version being opened
        self._done: dict[str, Any] = {}  # store id -> the opened store, or the exception (the reopen ended)
        self._retry: dict[str, tuple[tuple, float, float]] = {}  # store id -> (its version, when, the wait after)

    def reopening(self, sid: str) -> bool:
        """Whether the store ``sid`` is being opened again, or waits to be after a failed persist
        (a request naming it is a 503)."""
        return sid in self._reopening or sid in self._retry

    def soon(self) -> None:
        """Look at every store at the next request, whenever it comes (a brick just failed its
        check: its store may have been rewritten a moment ago)."""
        for w in self._files.values():
            w.soon()

    def refresh(self, svc: Any, sids: Any = None) -> None:
        """Put in place the stores of ``svc`` (a :class:`~hevr.serve.service.Service`) whose
        reopen ended, then start a reopen of every store (``sids``: these only) whose
        ``zarr.json`` changed, at most one look per ``interval`` each. Call it from one thread
        (the event loop's): it never blocks."""
        self._finish(svc)
        for sid in list(svc.stores if sids is None else sids):
            w = self._files.get(sid)
            if w is None or sid not in svc.stores or sid in self._reopening:
                continue
            retry = self._retry.get(sid)
            key: tuple[Any, ...] | None
            if retry is not None:
                if self.clock() < retry[1]:
                    continue
                key = retry[0]
            else:
                key = w.look()
            if key is None:
                continue
            if is_missing(key):  # being swapped: looked at again when it changes
                w.fail(key)
                continue
            self._reopening[sid] = key
            threading.Thread(
                target=self._reopen, args=(svc, sid, svc.stores[sid]), name=f"hevr-reopen-{sid}", daemon=True
            ).start()

    def _reopen(self, svc: Any, sid: str, old: Any) -> None:
        """Open the store ``sid`` (served now as ``old``) again, on its own thread; :meth:`_finish`
        puts it in place."""
        try:
            ev = open_volume(old.path)
            if old.resident is not None:
                try:
                    ev = ev.persist(old.resident.channels, client=svc.client, backend=svc.backend)
                except Exception as exc:  # noqa: BLE001 -- said by _put; tried again after a while
                    raise _PersistFailed(f"{type(exc).__name__}: {exc}") from exc
            result: Any = ev
        except BaseException as exc:  # noqa: BLE001 -- said by _finish, on the event loop's thread
            result = exc
        with self._lock:
            self._done[sid] = result

    def _finish(self, svc: Any) -> None:
        with self._lock:
            done, self._done = self._done, {}
        for sid, result in done.items():
            key = self._reopening.pop(sid)
            if sid in svc.stores:
                self._put(svc, sid, key, result)

    def _put(self, svc: Any, sid: str, key: tuple, ev: Any) -> None:
        old, w = svc.stores[sid], self._files[sid]
        retry = self._retry.pop(sid, None)
        if isinstance(ev, _PersistFailed):
            wait = RETRY_FIRST if retry is None else min(2 * retry[2], RETRY_MAX)
            self._retry[sid] = (key, self.clock() + wait, wait)
            log.error(
                "store %s changed on disk and opened again, but could not be made resident (%s); the store %s "
                "is answered 503 and tried again in %g s",
                old.path,
                ev,
                sid,
                wait,
            )
            return
        if isinstance(ev, BaseException):
            if not isinstance(ev, (HevrError, OSError, ValueError)):  # a bug: its traceback
                log.error(
                    "store %s: opening it again failed; still serving the store %s as opened",
                    old.path,
                    sid,
                    exc_info=ev,
                )
            elif w.fail(key):
                log.error(
                    "store %s changed on disk but cannot be opened yet (%s); still serving the store %s as opened",
                    old.path,
                    ev,
                    sid,
                )
            w.fail(key)  # tried again once the file changes again
            return
        new = ev.meta.store_id
        if new != sid and new in svc.stores:
            log.error(
                "store %s changed on disk into the store %s, which is already served (from %s); still "
                "serving the store %s as opened",
                old.path,
                new,
                svc.stores[new].path,
                sid,
            )
            w.fail(key)
            return
        name = svc.name_of.pop(sid, None)
        items = list(svc.stores.items())  # in place, in its order: the listing keeps it
        svc.stores.clear()
        svc.stores.update((new, ev) if k == sid else (k, v) for k, v in items)
        if name is not None:
            svc.names[name] = new
            svc.name_of[new] = name
        w.accept(key)
        self._files[new] = self._files.pop(sid)
        if new != sid:
            log.warning(
                "store %s was re-encrypted: now serving the store %s%s in place of %s (tokens that list "
                "store ids need the new one)",
                old.path,
                new,
                f" as {name!r}" if name else "",
                sid,
            )
        else:
            log.warning("store %s (%s) changed on disk: opened again", sid, old.path)
