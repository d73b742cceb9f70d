"""Running task lists on the active Dask scheduler, with an optional progress bar.

hevr never starts a cluster by itself: it uses the client it is given, else the active
``distributed`` client (``default_client()``), else Dask's default scheduler.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Any, Sequence

import dask
from dask.diagnostics import ProgressBar
from distributed import as_completed, default_client

log = logging.getLogger(__name__)

__all__ = ["active_client", "compute"]


def active_client(client: Any = None) -> Any:
    """The explicit ``client``, else the active distributed client, else None."""
    if client is not None:
        return client
    try:
        return default_client()
    except ValueError:
        return None


class _Bar:
    """A minimal text progress bar on stderr (library code never prints to stdout)."""

    def __init__(self, total: int, desc: str, enabled: bool) -> None:
        self.total, self.desc, self.enabled = total, desc, enabled and total > 0
        self.done = 0
        self.start = time.perf_counter()
        self._last = 0.0
        # Not a terminal (logs, CI, notebooks): a line per 10 % instead of carriage-return frames.
        self.tty = bool(getattr(sys.stderr, "isatty", lambda: False)())
        self._decile = -1
        if self.enabled:
            self._draw(force=True)

    def update(self, k: int = 1) -> None:
        self.done += k
        if self.enabled:
            self._draw(force=self.done >= self.total)

    def _draw(self, force: bool = False) -> None:
        now = time.perf_counter()
        if not self.tty:
            decile = int(10 * self.done / self.total)
            if decile != self._decile:
                self._decile = decile
                sys.stderr.write(f"{self.desc}: {self.done}/{self.total} tasks, {now - self.start:.1f}s\n")
            return
        if not force and now - self._last < 0.2:
            return
        self._last = now
        frac = self.done / self.total
        width = 30
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        el = now - self.start
        sys.stderr.write(f"\r{self.desc} [{bar}] {self.done}/{self.total} {el:6.1f}s")
        if self.done >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def compute(tasks: Sequence[Any], *, client: Any = None, progress: bool = True, desc: str = "hevr",
            keep: int = 0) -> list[Any]:
    """Compute dask delayed ``tasks`` on the active scheduler; results in task order.

    On a distributed client the last ``keep`` tasks are computed but not gathered: their
    futures stand in their place and their data stays on the workers (the render keeps its
    ray sums there for re-colouring). Without a client every result comes back.
    """
    tasks = list(tasks)
    if not tasks:
        return []
    client = active_client(client)
    t0 = time.perf_counter()
    if client is not None:
        futures = client.compute(tasks)
        bar = _Bar(len(futures), desc, progress)
        for _ in as_completed(futures, loop=client.loop):  # this client's, not the default one
            bar.update()
        cut = len(futures) - keep
        results = list(client.gather(futures[:cut])) + list(futures[cut:])
    else:
        if progress and len(tasks) > 1:

            with ProgressBar(out=sys.stderr):
                results = list(dask.compute(*tasks))
        else:
            results = list(dask.compute(*tasks))
    log.info("%s: %d tasks in %.2f s (%s)", desc, len(tasks), time.perf_counter() - t0,
             "distributed" if client is not None else "default scheduler")
    return results
