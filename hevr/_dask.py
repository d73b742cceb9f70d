"""Running task lists on the active Dask scheduler, with hevr's progress display
(:mod:`hevr._progress`: a widget in Jupyter, a bar on a terminal, log lines otherwise).

hevr never starts a cluster by itself: it uses the client it is given, else the active
``distributed`` client (``default_client()``), else Dask's default scheduler.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Sequence

import dask
from distributed import as_completed, default_client

from ._progress import Progress, TaskCounter

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
        bar = Progress(len(futures), desc, progress)
        failed = False
        try:
            for fut in as_completed(futures, loop=client.loop):  # this client's, not the default one
                failed = failed or fut.status == "error"
                bar.update()
        finally:
            bar.close(failed=failed)
        cut = len(futures) - keep
        results = list(client.gather(futures[:cut])) + list(futures[cut:])
    else:
        bar = Progress(0, desc, progress)  # the callback learns the number of graph tasks
        with TaskCounter(bar):
            results = list(dask.compute(*tasks))
    log.info("%s: %d tasks in %.2f s (%s)", desc, len(tasks), time.perf_counter() - t0,
             "distributed" if client is not None else "default scheduler")
    return results
