"""A store rewritten under a running ``hevr serve`` is noticed and opened again
(:class:`StoreWatch`).

The owner re-encrypts a served store in place (``hevr encrypt --overwrite``: a new store id), or
adds pyramid levels to it (``hevr pyramid``: the same id, new metadata). The handle the server
opened still holds the old metadata and digests, so every brick it reads from the new store fails
its digest check ("corrupted, truncated, swapped with another brick or copied from another
store"). Before a request names a store, the server ``stat``\\ s that store's ``zarr.json`` (the
root document that holds its metadata), at most once a second per store (:data:`CHECK_SECONDS`);
when its inode, size or modification time changed, the store is opened again
(:func:`hevr.open_volume`) and served under the same name: its new id from then on, the old id no
longer (a token lists ids: give it the new one). A store resident on the workers
(``hevr serve --persist``) is made resident again. A new version that cannot be opened yet (still
being written) is logged, and the old handle stays until the file changes again. A brick that
fails its check has every store looked at by the next request (:meth:`StoreWatch.soon`), so a
render that came within the second after a rewrite costs one failed request at most.

Only stores on a local (or mounted) filesystem are watched; a store behind a URL (``s3://``, ...)
is served as opened: restart ``hevr serve`` after re-encrypting it.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import Any

from ..errors import HevrError
from ..store.reader import open_volume

log = logging.getLogger("hevr.serve")

__all__ = ["CHECK_SECONDS", "StoreWatch"]

CHECK_SECONDS = 1.0


def _key(path: str) -> tuple | None:
    """The stat key of a local store's ``zarr.json`` (None: not a local store, or nothing there)."""
    if "://" in str(path):
        return None
    try:
        st = os.stat(os.path.join(path, "zarr.json"))
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


class StoreWatch:
    """The stat keys of the served stores' ``zarr.json`` and when each was last looked at.

    Parameters
    ----------
    stores : dict
        Store id -> opened store, as served now.
    interval : float
        Seconds between two looks at one store (default :data:`CHECK_SECONDS`).
    clock : callable
        The monotonic clock (tests pass their own).
    """

    def __init__(self, stores: dict, *, interval: float = CHECK_SECONDS,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.interval = float(interval)
        self._clock = clock
        self._key = {sid: _key(ev.path) for sid, ev in stores.items()}
        self._checked = {sid: clock() for sid in stores}
        self._failed: dict[str, tuple] = {}

    def soon(self) -> None:
        """Look at every store at the next request, whenever it comes (a brick just failed its
        check: its store may have been rewritten a moment ago)."""
        self._checked = dict.fromkeys(self._checked, float("-inf"))

    def refresh(self, svc: Any, sids: Any = None) -> None:
        """Open again every store of ``svc`` (a :class:`~hevr.serve.service.Service`; ``sids``:
        these only) whose ``zarr.json`` changed, at most once per ``interval`` each."""
        now = self._clock()
        for sid in list(svc.stores if sids is None else sids):
            if sid not in svc.stores or now - self._checked.get(sid, now) < self.interval:
                continue
            self._checked[sid] = now
            key = _key(svc.stores[sid].path)
            if key is None or key == self._key.get(sid) or key == self._failed.get(sid):
                continue
            self._reopen(svc, sid, key, now)

    def _reopen(self, svc: Any, sid: str, key: tuple, now: float) -> None:
        old = svc.stores[sid]
        try:
            ev = open_volume(old.path)
            if old.resident is not None:
                ev = ev.persist(old.resident.channels, client=svc.client, backend=svc.backend)
        except (HevrError, OSError, ValueError) as exc:
            if self._failed.get(sid) != key:
                log.error("store %s changed on disk but cannot be opened yet (%s); still serving the store %s as "
                          "opened", old.path, exc, sid)
            self._failed[sid] = key
            return
        new = ev.meta.store_id
        if new != sid and new in svc.stores:
            log.error("store %s changed on disk into the store %s, which is already served (from %s); still "
                      "serving the store %s as opened", old.path, new, svc.stores[new].path, sid)
            self._failed[sid] = key
            return
        name = svc.name_of.pop(sid, None)
        items = list(svc.stores.items())  # in place, in its order: the listing keeps it
        svc.stores.clear()
        svc.stores.update((new, ev) if k == sid else (k, v) for k, v in items)
        if name is not None:
            svc.names[name] = new
            svc.name_of[new] = name
        for table in (self._key, self._checked, self._failed):
            table.pop(sid, None)
        self._key[new], self._checked[new] = key, now
        if new != sid:
            log.warning("store %s was re-encrypted: now serving the store %s%s in place of %s (tokens that list "
                        "store ids need the new one)", old.path, new, f" as {name!r}" if name else "", sid)
        else:
            log.warning("store %s (%s) changed on disk: opened again", sid, old.path)
