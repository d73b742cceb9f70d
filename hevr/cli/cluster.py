"""The Dask client of a command: ``--scheduler ADDRESS`` joins a running cluster (``--own-cluster``:
declared this process's own, so that a private key may be used beside it), ``--workers N``
starts a local one of N worker processes (1 thread each) for the command, neither uses Dask's
default threaded scheduler; and the ``compute:`` line that says which.

Its own module because it imports :mod:`distributed` (a quarter of a second): only the commands
that compute import it, when they run (:mod:`hevr.cli.parser`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Iterator
from typing import Any

import dask
from dask.utils import parse_timedelta
from distributed import Client, LocalCluster
from distributed.comm.addressing import parse_address
from distributed.comm.registry import get_backend
from distributed.core import Status

from ..runtime.scheduler import own_cluster, workers_of
from .util import UsageError

__all__ = ["check_scheduler", "dask_client", "describe_client"]

log = logging.getLogger(__name__)

# The least time the worker processes this command starts on this machine get to reach their
# scheduler. Dask's default, 30 s, is for remote peers; local workers that start slowly because the
# machine is busy (a 2-core machine at load 20: issue 49) are not a network failure.
LOCAL_START_TIMEOUT = 120.0


def _local_start_timeout() -> float:
    """Dask's connect timeout, raised to :data:`LOCAL_START_TIMEOUT` (a larger configured one is kept).

    >>> with dask.config.set({"distributed.comm.timeouts.connect": "30s"}):
    ...     _local_start_timeout()
    120.0
    >>> with dask.config.set({"distributed.comm.timeouts.connect": "10m"}):
    ...     _local_start_timeout()
    600.0
    """
    configured = parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), default="seconds")
    return max(float(configured or 0), LOCAL_START_TIMEOUT)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, own: bool = False) -> Iterator[Any]:
    """Join ``scheduler``, or start ``workers`` local worker processes, or use Dask's default.

    ``own`` (``--own-cluster``): declare the ``scheduler``'s cluster this process's own
    (:func:`hevr.own_cluster`), so that a private key may be used beside it; a cluster joined
    otherwise is foreign (:class:`hevr.ForeignClusterError` where the key would be used), unless
    ``$HEVR_OWN_CLUSTER`` names it. A local cluster started here is this process's own anyway.

    Yields the ``distributed.Client`` (or None); closes what it opened.
    """
    if own and not scheduler:
        raise UsageError(
            "--own-cluster: expected --scheduler ADDRESS as well (a cluster this command starts, "
            "or Dask's default scheduler, is this process's own already)"
        )
    if scheduler:
        check_scheduler(scheduler)
        log.info("connecting to the Dask scheduler at %s", scheduler)
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise OSError(f"--scheduler: cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
        if own:
            own_cluster(client)
        try:
            yield client
        finally:
            client.close()
    elif workers:
        log.info("starting a local Dask cluster: %d worker processes, 1 thread each", workers)
        # _sigint_ignored: the worker processes inherit it, so Ctrl-C stops this one only; the connect
        # timeout travels to them with the nannies' config
        with _sigint_ignored(), dask.config.set({"distributed.comm.timeouts.connect": _local_start_timeout()}):
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=logging.ERROR,
            )
        try:
            client = Client(cluster)
            try:
                yield client
            except KeyboardInterrupt:
                _stop_workers(cluster)
                raise
            finally:
                client.close()
        finally:
            cluster.close()
    else:
        yield None


def check_scheduler(address: str) -> None:
    """Refuse a ``--scheduler`` address Dask cannot parse (an unknown scheme, no host) before connecting.

    >>> check_scheduler("garbage://x")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hevr.cli.util.UsageError: --scheduler: expected a Dask scheduler address like ..., got 'garbage://x' (unknown ...)
    """
    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if not location:
            raise ValueError("no host")
    except ValueError as exc:
        raise UsageError(
            f"--scheduler: expected a Dask scheduler address like tcp://10.0.0.5:8786, got {address!r} ({exc})"
        ) from None


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT while the local cluster's worker processes are spawned. A terminal's Ctrl-C
    goes to the whole process group: each worker would die with a page of Dask tracebacks. A
    process started with SIGINT ignored keeps ignoring it (Python installs its handler only
    over the default), so the interrupt reaches this process alone, which closes the cluster."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _stop_workers(cluster: Any) -> None:
    """After Ctrl-C: end the local worker processes at once (SIGKILL) instead of waiting for
    their running tasks — gmpy2 holds the GIL, so a worker answers a polite close only after its
    brick — and keep Dask's complaints about the vanished workers off the terminal. A brick
    being written is not marked done, so ``--resume`` encrypts it again; nothing finished is lost.

    Each nanny is told first that it is closing: a nanny whose worker dies while it runs starts a
    new worker process, and the cluster's close then waited for that one to start and stop (seconds
    on a loaded machine: issue 49)."""
    for name in ("distributed", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    for nanny in list(getattr(cluster, "workers", {}).values()):
        pid = getattr(nanny, "pid", None)
        if getattr(nanny, "status", None) == Status.running:
            nanny.status = Status.closing_gracefully  # its worker's exit closes it: no new worker
        if pid:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


def describe_client(client: Any) -> str:
    if client is None:
        return "Dask's default (threaded) scheduler"
    n: int | str
    try:
        n = len(workers_of(client))
    except Exception:  # pragma: no cover - informational only
        n = "?"
    try:
        board = f", dashboard {client.dashboard_link}" if client.dashboard_link else ""
    except Exception:  # pragma: no cover - no dashboard (bokeh missing, or disabled)
        board = ""
    return f"Dask cluster {client.scheduler.address} ({n} worker{'' if n == 1 else 's'}{board})"
