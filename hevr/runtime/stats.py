"""Per-process accounting of where render tasks spend their time.

Every map / merge / finish task adds its phase times here (a few ``perf_counter`` calls
per task, negligible next to one modular multiplication per pair). The benchmark reads
and resets the totals on every worker with ``client.run(hevr.runtime.stats.take)`` to split a
render's wall time into the encrypted kernel and everything else. Nothing secret is
recorded: only seconds and counts of public work.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager

_LOCK = threading.Lock()
_SECONDS: defaultdict[str, float] = defaultdict(float)
_COUNTS: defaultdict[str, int] = defaultdict(int)


def add(phase: str, seconds: float, count: int = 0) -> None:
    """Add ``seconds`` (and ``count`` units of work, e.g. kernel pairs) to ``phase``."""
    with _LOCK:
        _SECONDS[phase] += seconds
        _COUNTS[phase] += count


@contextmanager
def timed(phase: str, count: int = 0) -> Iterator[None]:
    """Context manager form of :func:`add`.

    Examples
    --------
    >>> _ = take()
    >>> with timed("demo", 3):
    ...     pass
    >>> snap = take()
    >>> snap["counts"]["demo"], snap["seconds"]["demo"] >= 0
    (3, True)
    """
    t0 = time.perf_counter()
    try:
        yield
    finally:
        add(phase, time.perf_counter() - t0, count)


def take(reset: bool = True) -> dict[str, dict[str, float]]:
    """Totals of this process since the last reset: ``{"seconds": {...}, "counts": {...}}``."""
    with _LOCK:
        out: dict[str, dict[str, float]] = {"seconds": dict(_SECONDS), "counts": dict(_COUNTS)}
        if reset:
            _SECONDS.clear()
            _COUNTS.clear()
    return out
