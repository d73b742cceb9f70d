"""Timing, machine and cluster helpers shared by the benchmark cases."""

from __future__ import annotations

import contextlib
import datetime
import logging
import os
import platform
import resource
import secrets
import subprocess
import time
import timeit
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import dask
import distributed
import gmpy2
import numpy
import zarr
from distributed import Client, LocalCluster
from gmpy2 import mpz

from .. import __version__
from ..runtime import stats
from ..runtime.scheduler import workers_of


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """``(fn(), wall seconds)``."""
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def mulmod_seconds(bits: int, number: int = 5000, repeat: int = 7) -> float:
    """Best time of one bare ``a * b % n2`` with ``n2`` of ``2 * bits`` bits (this process)."""
    n = mpz(secrets.randbits(bits)) | 1 | (mpz(3) << (bits - 2))
    n2 = n * n
    a, b = mpz(secrets.randbelow(int(n2))), mpz(secrets.randbelow(int(n2)))
    return min(timeit.repeat(lambda: a * b % n2, number=number, repeat=repeat)) / number


def fixed_base_seconds(private_key: Any, number: int = 100) -> float:
    """Best per-call time of one owner-side mask: the two fixed-base table exponentiations
    (mod p² and q²) and their CRT combination — the floor of one secure encryption."""
    owner = private_key.owner
    owner.mask()  # tables built outside the timing
    return min(timeit.repeat(owner.mask, number=number, repeat=5)) / number


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _git_commit() -> str | None:
    """Commit of the hevr checkout being measured (None when installed from a wheel)."""

    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty"], capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def machine() -> dict[str, Any]:
    """Date, CPU, cores, OS and the versions of everything on the hot path."""

    try:
        import phe

        phe_version = phe.__version__
    except ImportError:  # pragma: no cover - phe is in the test extra
        phe_version = None
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "os": f"{platform.system()} {platform.release()}",
        "memory_gib": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
        "versions": {
            "python": platform.python_version(),
            "hevr": __version__,
            "gmpy2": gmpy2.version(),
            "numpy": numpy.__version__,
            "dask": dask.__version__,
            "distributed": distributed.__version__,
            "zarr": zarr.__version__,
            "phe": phe_version,
        },
        "load_average_start": os.getloadavg()[0],
        "commit": _git_commit(),
    }


def dir_bytes(path: str | Path) -> int:
    """Bytes of all files under ``path`` (what the store occupies, metadata included)."""
    total = 0
    for root, _dirs, files in os.walk(path):
        total += sum(os.path.getsize(os.path.join(root, f)) for f in files)
    return total


def _peak_rss_bytes() -> int:
    """Peak RSS of this process since the last :func:`_reset_peak` (VmHWM), else since start."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB


def _reset_peak() -> bool:
    """Reset this process's peak RSS to its current RSS (Linux: ``5 > /proc/self/clear_refs``)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


class Workers:
    """The compute side of a benchmark: a LocalCluster we own, a user's client, or none.

    ``fresh()`` resets the workers' task statistics and their peak RSS (Linux VmHWM via
    ``/proc/self/clear_refs``), so that the peak of the next stage is that stage's alone;
    where the reset is not possible the peak is since the process started. Workers are never
    restarted: a restart waits for the nanny and lost two minutes per stage when tried.
    """

    def __init__(self, client: Any, own: bool, n_workers: int) -> None:
        self.client, self.own, self.n_workers = client, own, n_workers

    def fresh(self) -> bool:
        """Reset statistics and peak memory; True if the peak could be reset everywhere."""
        self._run(_warm)
        return all(self._run(_reset_peak))

    def _run(self, fn: Callable[[], Any]) -> list[Any]:
        return [fn()] if self.client is None else list(self.client.run(fn).values())

    def take_stats(self) -> dict[str, dict]:
        """Sum of the per-process task phase totals of every worker (and reset them)."""
        out: dict[str, dict] = {"seconds": {}, "counts": {}}
        for snap in self._run(stats.take):
            for kind in out:
                for k, v in snap[kind].items():
                    out[kind][k] = out[kind].get(k, 0) + v
        return out

    def peak_rss(self) -> int:
        """Largest peak RSS of any worker process, bytes."""
        return max(self._run(_peak_rss_bytes))


def _warm() -> None:
    stats.take()  # hevr is imported on the worker with this module: imports are not part of any timing


@contextlib.contextmanager
def workers(n_workers: int, scheduler: str | None = None) -> Iterator[Workers]:
    """A ``Workers`` on a new LocalCluster (1 thread per process), on ``scheduler``, or with
    ``n_workers=0`` in this process on Dask's threaded scheduler (no cluster at all)."""

    if not scheduler and n_workers == 0:
        yield Workers(None, False, 1)
        return
    if scheduler:
        with Client(scheduler) as client:
            n = len(workers_of(client))
            client.run(_warm)
            yield Workers(client, False, n)
        return
    # distributed logs every restart at INFO; the benchmark's own log says what happens
    logging.getLogger("distributed").setLevel(logging.WARNING)
    logging.getLogger("distributed.nanny").setLevel(logging.ERROR)  # "Restarting worker" is expected here
    with (
        LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        client.run(_warm)
        yield Workers(client, True, n_workers)
