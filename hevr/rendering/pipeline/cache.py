"""The render cache: the merged encrypted ray sums of the last views rendered in this process.

A render keeps the per-component ray sums of its view (:class:`~hevr.rendering.pipeline.sums.RaySums`)
under a key of the store, the level, the view and the plan's sampling, step, weight digits, channel and
tile, so that another density or transfer function on the same view only redoes the finishing
(:func:`hevr.render` with ``cache=True``). At most :data:`CACHE_SIZE` views are kept, least recently
used first out; renders on several threads share the cache under one lock.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any

from .sums import RaySums

__all__ = ["CACHE_SIZE", "cached", "clear_cache", "keep"]

_CACHE: OrderedDict[tuple[Any, ...], RaySums] = OrderedDict()
CACHE_SIZE = 2
_CACHE_LOCK = threading.Lock()  # renders run on several threads at once (hevr serve, a notebook's threads)


def clear_cache() -> None:
    """Forget every cached set of ray sums."""
    with _CACHE_LOCK:
        _CACHE.clear()


def cached(key: tuple, client: Any) -> RaySums | None:
    """The cached ray sums of ``key`` usable on ``client`` (now the most recent), else None; sums
    whose futures belong to another (or a closed) client are dropped. One step under the lock: a
    render on another thread cannot evict them between the look-up and the use."""
    with _CACHE_LOCK:
        sums = _CACHE.get(key)
        if sums is not None and not sums.usable(client):
            del _CACHE[key]
            sums = None
        if sums is not None:
            _CACHE.move_to_end(key)
        return sums


def keep(key: tuple, sums: RaySums) -> None:
    """Cache ``sums`` under ``key``, dropping the least recently used beyond :data:`CACHE_SIZE`."""
    with _CACHE_LOCK:
        _CACHE[key] = sums
        _CACHE.move_to_end(key)
        while len(_CACHE) > CACHE_SIZE:
            _CACHE.popitem(last=False)
