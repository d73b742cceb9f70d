"""Running task lists on the active Dask scheduler, with hevr's progress display
(:mod:`hevr._progress`: a widget in Jupyter, a bar on a terminal, log lines otherwise).

hevr never starts a cluster by itself: it uses the client it is given, else the active
``distributed`` client (``default_client()``), else Dask's default scheduler.
"""

from __future__ import annotations

import contextlib
import logging
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Sequence

import dask
import dask.threaded
from distributed import as_completed, default_client

from . import _cancel
from ._progress import Progress, TaskCounter

log = logging.getLogger(__name__)

__all__ = ["active_client", "compute", "warn_if_remote"]

_WARNED_SCHEDULERS: set = set()
_LOOPBACK = ("127.", "localhost", "[::1]", "::1")


def warn_if_remote(client: Any) -> None:
    """Once per scheduler: warn when this process is a Dask client of a scheduler that is not on
    this machine's loopback. Dask's protocol unpickles what the cluster sends, so its workers can
    run code in this process — the key holder's, where it renders and decrypts: the local Dask path
    is for clusters the key holder runs; a server's cluster is reached through ``hevr serve`` and
    :func:`hevr.connect`, which carries data only.

    >>> warn_if_remote(None)  # Dask's default scheduler: nothing to say
    """
    if client is None:
        return
    try:
        address = str(client.scheduler.address)
    except Exception:  # pragma: no cover - a closed client: its render fails on its own
        return
    host = address.split("://", 1)[-1]
    if address.startswith("inproc://") or host.startswith(_LOOPBACK) or address in _WARNED_SCHEDULERS:
        return
    _WARNED_SCHEDULERS.add(address)
    warnings.warn(f"this process is a Dask client of the scheduler at {address}, which is not on this machine: "
                  "Dask unpickles what that cluster sends, so its workers can run code here, where your private key "
                  "is. Use the Dask path only on a cluster you run; render on another party's cluster with "
                  "'hevr serve' there and hevr.connect(URL) here (data only, never unpickled)", UserWarning,
                  stacklevel=3)


def active_client(client: Any = None) -> Any:
    """The explicit ``client``, else the active distributed client, else None."""
    if client is not None:
        return client
    try:
        return default_client()
    except ValueError:
        return None


def compute(tasks: Sequence[Any], *, client: Any = None, progress: bool = True, desc: str = "hevr",
            keep: int = 0, on_result: Callable[[int, Any], None] | None = None, steps: int = 0,
            unit: str = "tasks") -> list[Any]:
    """Compute dask delayed ``tasks`` on the active scheduler; results in task order.

    On a distributed client the last ``keep`` tasks are computed but not gathered: their
    futures stand in their place and their data stays on the workers (the render keeps its
    ray sums there for re-colouring). Without a client every result comes back.

    ``on_result(i, value)`` is called for every gathered task i: on a distributed client as
    each one completes (the client's work on it overlaps the tasks still running), on Dask's
    default scheduler once all have run.

    ``steps`` (in ``unit``, e.g. the ciphertexts of an encryption): the tasks report finer
    progress with :func:`hevr._cancel.add_steps`, shown with a rate and the time left; tasks on
    a ``distributed`` worker send it as the worker's ``hevr-steps`` events.
    """
    tasks = list(tasks)
    if not tasks:
        return []
    client = active_client(client)
    t0 = time.perf_counter()
    if client is not None:
        futures = client.compute(tasks)
        bar = Progress(len(futures), desc, progress, steps=steps, unit=unit)
        if steps:
            client.subscribe_topic(_cancel.TOPIC, lambda event: bar.step(int(event[1])))
        failed = False
        cut = len(futures) - keep
        index = {f.key: i for i, f in enumerate(futures)}
        got: dict[int, Any] = {}
        try:
            for fut in as_completed(futures, loop=client.loop):  # this client's, not the default one
                failed = failed or fut.status == "error"
                bar.update()
                i = index[fut.key]
                if on_result is not None and not failed and i < cut:
                    got[i] = fut.result()
                    on_result(i, got[i])
        finally:
            if steps:
                with contextlib.suppress(Exception):  # a client closing after an interrupt
                    client.unsubscribe_topic(_cancel.TOPIC)
                if not failed and all(f.status == "finished" for f in futures):
                    bar.step(max(0, steps - bar.steps_done))  # the last events may still be on their way
            bar.close(failed=failed)
        rest = [i for i in range(cut) if i not in got]
        got.update(zip(rest, client.gather([futures[i] for i in rest])))
        results = [got[i] for i in range(cut)] + list(futures[cut:])
    else:
        bar = Progress(0, desc, progress, steps=steps, unit=unit)  # the callback learns the number of graph tasks
        with TaskCounter(bar), _cancel.counting(bar.step):
            results = _compute_local(tasks)
        if on_result is not None:
            for i, value in enumerate(results[:len(results) - keep] if keep else results):
                on_result(i, value)
    log.info("%s: %d tasks in %.2f s (%s)", desc, len(tasks), time.perf_counter() - t0,
             "distributed" if client is not None else "default scheduler")
    return results


def _compute_local(tasks: list[Any]) -> list[Any]:
    """``dask.compute`` on Dask's default scheduler. The threaded scheduler gets a pool of its
    own that is shut down before this returns or raises: when a task fails, dask raises at
    once while the tasks already running go on in the pool's threads, and a clean-up of what
    they write (a partial store) would race with them ("Directory not empty", files written
    after the removal). Here the tasks still running are waited for and those not started are
    dropped. (On a distributed client :func:`compute` waits for every future before raising.)"""
    scheduler = dask.base.get_scheduler(collections=tasks)
    if scheduler is not dask.threaded.get or dask.config.get("pool", None) is not None:
        return list(dask.compute(*tasks))
    workers = dask.config.get("num_workers", None) or dask.threaded.CPU_COUNT
    pool = ThreadPoolExecutor(max_workers=workers)
    _cancel.clear()
    try:
        return list(dask.compute(*tasks, pool=pool))
    except KeyboardInterrupt:  # Ctrl-C: the running tasks stop at their next check, not at their end
        _cancel.stop()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
