"""Stopping an interrupted job's tasks in this process, and counting their finer steps.

Ctrl-C reaches the thread that waits for Dask (:func:`hevr.runtime.scheduler.compute`); the tasks of Dask's
threaded scheduler run on in their pool, and the pool is waited for before the error goes on
(so that nothing is cleaned up while a task still writes). A long task — the encryption of a
brick, thousands of modular exponentiations — would hold the interrupt for many seconds. So
:func:`compute` calls :func:`stop` on ``KeyboardInterrupt``, and the long loops call
:func:`check` between small batches: a task stops before its next batch (never in the middle
of a write), within a fraction of a second.

The same loops report their batches to :func:`add_steps`: a progress display of this process
(:class:`hevr.runtime.progress.Progress`, attached with :func:`counting`) then moves with every batch,
not only when a whole task ends; a task on a ``distributed`` worker sends its steps to the
client as worker events, at most one every :data:`STEP_INTERVAL` seconds inside
:func:`batched_steps` (one per batch of 64 values was 147,000 events for a 72 MiB volume: the
scheduler's time, and the worker's memory while a busy scheduler fell behind).

The stop flag reaches only this process's tasks: on a cluster the
CLI ends its local workers (:mod:`hevr.cli.cluster`).

One job among several (a render of ``hevr serve`` whose client left) is stopped with its own
:class:`Scope`: the thread that runs the job enters it (:func:`scope`), and
:func:`hevr.runtime.scheduler.compute` there cancels that job's futures on a ``distributed`` cluster, or starts
none of its remaining tasks on Dask's threaded scheduler, once :meth:`Scope.cancel` is called (from
any thread); the job then raises :class:`Cancelled`.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from distributed import get_worker

__all__ = [
    "TOPIC",
    "Cancelled",
    "Scope",
    "STEP_INTERVAL",
    "add_steps",
    "batched_steps",
    "cancel_soon",
    "check",
    "clear",
    "counting",
    "current",
    "scope",
    "stop",
    "stopped",
]

#: The worker event that carries a task's finer progress steps to its client.
TOPIC = "hevr-steps"
#: Inside :func:`batched_steps`, a worker's task sends its steps at most this often (seconds).
STEP_INTERVAL = 0.25

_STOP = threading.Event()
_LOCK = threading.Lock()
_SINKS: list[Callable[[int], None]] = []
_LOCAL = threading.local()


class Cancelled(Exception):
    """A job's :class:`Scope` was cancelled: its work stopped (not a failure of the work)."""


class Scope:
    """One job's cancellation: :meth:`cancel` (any thread) runs the callbacks registered with
    :meth:`on_cancel` (e.g. ``client.cancel(futures)``) once, and :meth:`check` raises from then on.

    >>> s = Scope(); seen = []
    >>> undo = s.on_cancel(lambda: seen.append("cancel futures"))
    >>> s.check(); s.cancel("client left"); s.cancel(); seen, s.cancelled, s.reason
    (['cancel futures'], True, 'client left')
    >>> try:
    ...     s.check()
    ... except Cancelled as exc:
    ...     print(exc)
    cancelled: client left
    """

    def __init__(self) -> None:
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._callbacks: list[Callable[[], None]] = []
        self.reason = ""

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def cancel(self, reason: str = "cancelled") -> None:
        with self._lock:
            if self._event.is_set():
                return
            self.reason = reason
            self._event.set()
            callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            with contextlib.suppress(Exception):  # a closed client: its work is gone anyway
                fn()

    def on_cancel(self, fn: Callable[[], None]) -> Callable[[], None]:
        """Run ``fn`` at :meth:`cancel` (at once if cancelled already); returns its removal."""
        with self._lock:
            if not self._event.is_set():
                self._callbacks.append(fn)
                return lambda: self._discard(fn)
        fn()
        return lambda: None

    def _discard(self, fn: Callable[[], None]) -> None:
        with self._lock:
            if fn in self._callbacks:
                self._callbacks.remove(fn)

    def check(self) -> None:
        """Raise :class:`Cancelled` once :meth:`cancel` was called."""
        if self._event.is_set():
            raise Cancelled(f"cancelled: {self.reason}")

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until cancelled (at most ``timeout`` seconds); whether it was."""
        return self._event.wait(timeout)


def cancel_soon(job: Scope, reason: str) -> None:
    """Cancel ``job`` from a thread of its own, returning at once (a callback such as a distributed
    client's ``cancel`` blocks on that client's loop, never on the caller's).

    >>> s = Scope(); cancel_soon(s, "client left"); s.wait(10), s.reason
    (True, 'client left')
    """
    if not job.cancelled:
        threading.Thread(target=job.cancel, args=(reason,), name="hevr-cancel", daemon=True).start()


@contextlib.contextmanager
def scope(s: Scope) -> Iterator[Scope]:
    """Run the block (in this thread) as the job of ``s``: :func:`current` returns it."""
    before = getattr(_LOCAL, "scope", None)
    _LOCAL.scope = s
    try:
        yield s
    finally:
        _LOCAL.scope = before


def current() -> Scope | None:
    """The :class:`Scope` this thread's job runs in (:func:`scope`), or None."""
    return getattr(_LOCAL, "scope", None)


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
    :data:`TOPIC`, which :func:`hevr.runtime.scheduler.compute` subscribes to)."""
    worker = _worker()
    if worker is not None:
        batch = getattr(_LOCAL, "steps", None)
        if batch is None:
            worker.log_event(TOPIC, int(k))
            return
        batch[0] += int(k)
        now = time.monotonic()
        if now - batch[1] >= STEP_INTERVAL:
            worker.log_event(TOPIC, batch[0])
            batch[0], batch[1] = 0, now
        return
    with _LOCK:
        sinks = list(_SINKS)
    for sink in sinks:
        sink(k)


@contextlib.contextmanager
def batched_steps() -> Iterator[None]:
    """In a task on a ``distributed`` worker, :func:`add_steps` in the block sends what it counted
    at most every :data:`STEP_INTERVAL` seconds, and the rest when the block ends (a task's loop
    of small batches). Elsewhere each call goes to the displays at once, as without it.

    >>> seen = []
    >>> with counting(seen.append), batched_steps():
    ...     add_steps(3); add_steps(4)
    >>> seen
    [3, 4]
    """
    if _worker() is None:
        yield
        return
    before = getattr(_LOCAL, "steps", None)
    _LOCAL.steps = batch = [0, time.monotonic()]
    try:
        yield
    finally:
        _LOCAL.steps = before
        if batch[0]:
            add_steps(int(batch[0]))  # [steps, time of the last event]: the count is an int


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
