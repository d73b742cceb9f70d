"""The Dask client of a command: ``--scheduler ADDRESS`` joins a running cluster, ``--workers N``
starts a local one of N worker processes (1 thread each) for the command, neither uses Dask's
default threaded scheduler; and the ``compute:`` line that says which.

Its own module because it imports :mod:`distributed` (a quarter of a second): only the commands
that compute import it, when they run (:mod:`hevr.cli.parser`).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from typing import Any

from distributed import Client, LocalCluster
from distributed.comm.addressing import parse_address
from distributed.comm.registry import get_backend

from .util import UsageError

__all__ = ["check_scheduler", "dask_client", "describe_client"]

log = logging.getLogger(__name__)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """Join ``scheduler``, or start ``workers`` local worker processes, or use Dask's default.

    Yields the ``distributed.Client`` (or None); closes what it opened.
    """
    if scheduler:
        check_scheduler(scheduler)
        log.info("connecting to the Dask scheduler at %s", scheduler)
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise OSError(f"--scheduler: cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
    elif workers:

        log.info("starting a local Dask cluster: %d worker processes, 1 thread each", workers)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
        try:
            client = Client(cluster)
            try:
                yield client
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
        raise UsageError(f"--scheduler: expected a Dask scheduler address like tcp://10.0.0.5:8786, got {address!r} "
                         f"({exc})") from None


def describe_client(client: Any) -> str:
    if client is None:
        return "Dask's default (threaded) scheduler"
    try:
        n = len(client.scheduler_info().get("workers", {}))
    except Exception:  # pragma: no cover - informational only
        n = "?"
    try:
        board = f", dashboard {client.dashboard_link}" if client.dashboard_link else ""
    except Exception:  # pragma: no cover - no dashboard (bokeh missing, or disabled)
        board = ""
    return f"Dask cluster {client.scheduler.address} ({n} workers{board})"
