"""Stopping an interrupted job's tasks in this process, and counting their finer steps.

Ctrl-C reaches the thread that waits for Dask (:func:`hevr._dask.compute`); the tasks of Dask's
threaded scheduler run on in their pool, and the pool is waited for before the error goes on
(so that nothing is cleaned up while a task still writes). A long task — the encryption of a
brick, thousands of modular exponentiations — would hold the interrupt for many seconds. So
:func:`compute` calls :func:`stop` on ``KeyboardInterrupt``, and the long loops call
:func:`check` between small batches: a task stops before its next batch (never in the middle
of a write), within a fraction of a second.

The same loops report their batches to :func:`add_steps`: a progress display of this process
(:class:`hevr._progress.Progress`, attached with :func:`counting`) then moves with every batch,
not only when a whole task ends; a task on a ``distributed`` worker sends its steps to the
client as worker events. The stop flag reaches only this process's tasks: on a cluster the
CLI ends its local workers (:mod:`hevr.cli.cluster`).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from typing import Any

from distributed import get_worker

__all__ = ["TOPIC", "add_steps", "check", "clear", "counting", "stop", "stopped"]

#: The worker event that carries a task's finer progress steps to its client.
TOPIC = "hevr-steps"

_STOP = threading.Event()
_LOCK = threading.Lock()
_SINKS: list[Callable[[int], None]] = []


def stop() -> None:
    """Ask every task of this process to stop at its next :func:`check`."""
    _STOP.set()


def clear() -> None:
    """A new job starts: tasks run again."""
    _STOP.clear()


def stopped() -> bool:
    """Whether :func:`stop` was called since the last :func:`clear`."""
    return _STOP.is_set()


def check() -> None:
    """Raise ``KeyboardInterrupt`` in a task when the job was interrupted (:func:`stop`).

    >>> clear(); check()
    >>> stop()
    >>> try:
    ...     check()
    ... except KeyboardInterrupt:
    ...     print("stopped")
    stopped
    >>> clear()
    """
    if _STOP.is_set():
        raise KeyboardInterrupt("the job was interrupted")


def add_steps(k: int) -> None:
    """``k`` more fine steps (e.g. ciphertexts) are done: for the displays of this process
    attached now, and in a task on a ``distributed`` worker for its client (an event of
    :data:`TOPIC`, which :func:`hevr._dask.compute` subscribes to)."""
    worker = _worker()
    if worker is not None:
        worker.log_event(TOPIC, int(k))
        return
    with _LOCK:
        sinks = list(_SINKS)
    for sink in sinks:
        sink(k)


def _worker() -> Any:
    """The ``distributed`` worker running the current task, or None."""
    try:
        return get_worker()
    except ValueError:  # not in a worker's task
        return None


@contextlib.contextmanager
def counting(sink: Callable[[int], None]) -> Iterator[None]:
    """Send the steps of :func:`add_steps` to ``sink`` while the block runs.

    >>> seen = []
    >>> with counting(seen.append):
    ...     add_steps(3)
    >>> add_steps(4); seen
    [3]
    """
    with _LOCK:
        _SINKS.append(sink)
    try:
        yield
    finally:
        with _LOCK:
            _SINKS.remove(sink)
