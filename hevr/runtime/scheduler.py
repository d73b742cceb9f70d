"""Running task lists on the active Dask scheduler, with hevr's progress display
(:mod:`hevr.runtime.progress`: a widget in Jupyter, a bar on a terminal, log lines otherwise).

hevr never starts a cluster by itself: it uses the client it is given, else the active
``distributed`` client (``default_client()``), else Dask's default scheduler.

The Dask path is for the key holder's own cluster: Dask unpickles what a cluster sends, so a private
key is used only beside a cluster this process started or the user declared its own
(:func:`own_cluster`, ``$HEVR_OWN_CLUSTER``); :func:`refuse_foreign_cluster` says no otherwise, and
another party's cluster is reached through ``hevr serve`` and :func:`hevr.connect` (data only).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import dask
import dask.threaded
from distributed import Client, LocalCluster, as_completed, default_client
from distributed.comm.addressing import normalize_address

from ..errors import ForeignClusterError, ParameterError
from . import cancel
from .progress import Progress, TaskCounter

log = logging.getLogger(__name__)

__all__ = [
    "OWN_CLUSTER_ENV",
    "active_client",
    "check_encryption_client",
    "compute",
    "declared_own",
    "is_own_cluster",
    "own_cluster",
    "refuse_foreign_cluster",
    "scheduler_address",
    "warn_if_remote",
    "workers_of",
]

OWN_CLUSTER_ENV = "HEVR_OWN_CLUSTER"  # <address>[,<address>…]: the opt-in of own_cluster, for the command line
_OWN_SCHEDULERS: set[str] = set()  # the scheduler addresses declared with own_cluster in this process
_WARNED_SCHEDULERS: set[str] = set()


def _normal(address: str) -> str:
    """A scheduler address as Dask's client reports it (``127.0.0.1:8786`` -> ``tcp://127.0.0.1:8786``);
    compared exactly afterwards, never by its host's spelling."""
    try:
        return normalize_address(address.strip())
    except (ValueError, TypeError):
        return address.strip()


def scheduler_address(client: Any) -> str | None:
    """The address of ``client``'s scheduler (None: Dask's default scheduler, or a closed client)."""
    if client is None:
        return None
    try:
        address = client.scheduler.address
    except Exception:  # a closed client: its work fails on its own
        return None
    return str(address) if address else None


def own_cluster(client_or_address: Any) -> str:
    """Declare a Dask cluster this process's own: the key holder's private key may be used beside it.

    Dask's protocol unpickles what a cluster sends, so its scheduler and its workers (a worker
    plugin, a crafted result) can run code in this process. hevr therefore refuses to use a private
    key (:func:`hevr.encrypt_volume` with a :class:`PrivateKey`, :func:`hevr.render_frame`, any
    decryption) while this process is a client of a scheduler it did not start
    (:class:`hevr.ForeignClusterError`) unless the cluster is declared here. Declaring it says:
    **this scheduler and its workers are mine; code they send runs in this process.** Declare only a
    cluster you run on machines you control; render on another party's cluster through its
    ``hevr serve`` with :func:`hevr.connect` instead (data only, never unpickled).

    Clusters this process started need no declaration: Dask's default scheduler (no client), a
    client of a cluster object made here (``Client()``, ``Client(LocalCluster(...))``) and an
    ``inproc://`` scheduler. The address is never judged by its spelling: ``tcp://127.0.0.1:8786``
    may be an ``ssh -L`` tunnel to another party's cluster.

    The same opt-in without code: the environment variable ``HEVR_OWN_CLUSTER=ADDRESS[,ADDRESS…]``
    (``hevr … --scheduler ADDRESS --own-cluster`` on the command line).

    Parameters
    ----------
    client_or_address : distributed.Client or str
        A client of the cluster (its scheduler's address is recorded) or the scheduler's address,
        e.g. ``"tcp://10.0.0.5:8786"``.

    Returns
    -------
    str
        The scheduler address recorded (for the rest of this process's life).

    Raises
    ------
    hevr.ParameterError
        For anything else (a closed client, an empty address).

    >>> own_cluster("tcp://10.0.0.5:8786")
    'tcp://10.0.0.5:8786'
    >>> _OWN_SCHEDULERS.discard("tcp://10.0.0.5:8786")
    """
    address = client_or_address if isinstance(client_or_address, str) else scheduler_address(client_or_address)
    if not address or not address.strip():
        raise ParameterError(
            "client_or_address: expected a distributed.Client or a scheduler address such as "
            f"tcp://10.0.0.5:8786, got {client_or_address!r}"
        )
    address = _normal(address)
    _OWN_SCHEDULERS.add(address)
    log.info("the Dask cluster at %s is declared this process's own: the private key may be used beside it", address)
    return address


def _declared() -> set[str]:
    """The addresses declared own: with :func:`own_cluster`, and in ``$HEVR_OWN_CLUSTER`` (read each time)."""
    env = os.environ.get(OWN_CLUSTER_ENV, "")
    return _OWN_SCHEDULERS | {_normal(a) for a in env.split(",") if a.strip()}


def declared_own(address: str) -> bool:
    """Whether the scheduler ``address`` was declared this process's own (:func:`own_cluster`,
    ``$HEVR_OWN_CLUSTER``), compared exactly after :func:`_normal`.

    >>> declared_own("tcp://192.0.2.7:8786")
    False
    """
    return _normal(address) in _declared()


def is_own_cluster(client: Any) -> bool:
    """Whether ``client``'s cluster is this process's own (no address guessing).

    Own: no client (Dask's default scheduler, in this process), an ``inproc://`` scheduler (only
    this process can reach one), a client of a ``LocalCluster`` made in this process
    (``client.cluster``, set by ``Client()`` and ``Client(LocalCluster(...))``, not by
    ``Client(address)``; other cluster objects — dask-gateway, SSH, Kubernetes — run on machines
    that may not be yours: declare them), or a scheduler address declared with :func:`own_cluster` or
    ``$HEVR_OWN_CLUSTER``. Anything else is foreign, whatever its host is called: a loopback
    address may be a tunnel, ``localhost.example.org`` is just a name.

    >>> is_own_cluster(None)
    True
    """
    if client is None:
        return True
    if isinstance(getattr(client, "cluster", None), LocalCluster):  # started by this process (Client(), or given)
        return True
    address = scheduler_address(client)
    if address is None:  # a closed client: nothing will run on it
        return True
    return address.startswith("inproc://") or declared_own(address)


def refuse_foreign_cluster(client: Any = None, doing: str = "using the private key") -> None:
    """Raise :class:`hevr.ForeignClusterError` when a private key is about to be used while the given
    client (default: the active one, ``distributed.default_client()``, if any) is a client of a
    cluster that is not this process's own (:func:`is_own_cluster`); nothing otherwise.

    Call it before the private key is used: at the start of every decryption, of an encryption
    with a :class:`PrivateKey`, of a key holder's render.

    >>> refuse_foreign_cluster(None)  # Dask's default scheduler, or no client at all: nothing to say
    """
    client = active_client(client)
    if is_own_cluster(client):
        return
    address = scheduler_address(client)
    raise ForeignClusterError(
        f"client: expected a Dask cluster this process started or declared its own, got the scheduler at {address} "
        f"while {doing}: Dask unpickles what that cluster sends, so its scheduler and workers can run code in this "
        "process, where the private key is. Render on another party's cluster through its 'hevr serve' with "
        "hevr.connect(URL) (data only, never unpickled); if the cluster is yours, declare it with "
        f"hevr.own_cluster(client) (or {OWN_CLUSTER_ENV}={address}, or --own-cluster with --scheduler)"
    )


def check_encryption_client(client: Any, private: bool) -> None:
    """Before :func:`hevr.encrypt_volume` sends its tasks (plaintext bricks; with a private key also
    p and q) to ``client`` (default: the active one): a private key beside a cluster that is not this
    process's own is refused (:func:`refuse_foreign_cluster`); a public key's plaintext bricks going
    to one are logged as a warning. No address guessing."""
    client = active_client(client)
    if private:
        refuse_foreign_cluster(client, "encrypt_volume with a PrivateKey (its tasks carry p and q)")
    elif not is_own_cluster(client):
        log.warning(
            "encrypt_volume sends plaintext bricks to the Dask workers of %s, a cluster this process did not "
            "start; encrypt only on machines the data owner controls (hevr.own_cluster(client) declares it "
            "yours)",
            scheduler_address(client),
        )


def warn_if_remote(client: Any) -> None:
    """Once per scheduler: warn when this process is a Dask client of a cluster that is not its own
    (:func:`is_own_cluster`; no address guessing) and renders there without holding a key. Dask's
    protocol unpickles what the cluster sends, so its workers can run code in this process; a key
    holder's steps beside such a client are refused (:func:`refuse_foreign_cluster`).

    >>> warn_if_remote(None)  # Dask's default scheduler: nothing to say
    """
    if is_own_cluster(client):
        return
    address = scheduler_address(client)
    if address in _WARNED_SCHEDULERS:
        return
    _WARNED_SCHEDULERS.add(str(address))
    warnings.warn(
        f"this process is a Dask client of the scheduler at {address}, which it did not start: Dask "
        "unpickles what that cluster sends, so its workers can run code here; keep private keys out of "
        "this process (hevr refuses to use one beside this client). Render on another party's cluster "
        "with 'hevr serve' there and hevr.connect(URL) here (data only, never unpickled); if the cluster "
        "is yours, declare it with hevr.own_cluster(client)",
        UserWarning,
        stacklevel=3,
    )


def workers_of(client: Any) -> dict[str, Any]:
    """The workers of ``client``'s cluster (address -> the scheduler's record of it), asked of
    the scheduler now. ``client.scheduler_info()["workers"]`` may be empty though workers run:
    the client's own refresh every 2 s, which asks for no workers, can replace the answer between
    its fetch and its return, and a loaded machine widens that window (issue 49: a render
    refused "a cluster with workers, got none" under load)."""
    if not isinstance(client, Client):  # a stand-in with scheduler_info() only (tests)
        return dict(client.scheduler_info().get("workers", {}))
    try:
        info = client.sync(client.scheduler.identity, n_workers=-1)
    except TypeError:  # distributed < 2025.4: identity() takes no argument and lists every worker
        info = client.sync(client.scheduler.identity)
    return dict(info.get("workers", {}))


def active_client(client: Any = None) -> Any:
    """The explicit ``client``, else the active distributed client, else None."""
    if client is not None:
        return client
    try:
        return default_client()
    except ValueError:
        return None


def compute(
    tasks: Sequence[Any],
    *,
    client: Any = None,
    progress: bool = True,
    desc: str = "hevr",
    keep: int = 0,
    on_result: Callable[[int, Any], None] | None = None,
    steps: int = 0,
    unit: str = "tasks",
) -> list[Any]:
    """Compute dask delayed ``tasks`` on the active scheduler; results in task order.

    On a distributed client the last ``keep`` tasks are computed but not gathered: their
    futures stand in their place and their data stays on the workers (the render keeps its
    ray sums there for re-colouring). Without a client every result comes back.

    ``on_result(i, value)`` is called for every gathered task i: on a distributed client as
    each one completes (the client's work on it overlaps the tasks still running), on Dask's
    default scheduler once all have run.

    ``steps`` (in ``unit``, e.g. the ciphertexts of an encryption): the tasks report finer
    progress with :func:`hevr.runtime.cancel.add_steps`, shown with a rate and the time left; tasks on
    a ``distributed`` worker send it as the worker's ``hevr-steps`` events.

    In a job's :class:`hevr.runtime.cancel.Scope` (:func:`hevr.runtime.cancel.scope`), cancelling the scope
    cancels these futures, or starts none of the remaining tasks on the threaded scheduler, and
    this raises :class:`hevr.runtime.cancel.Cancelled` (``hevr serve``'s render whose client left).
    """
    job = cancel.current()  # a job of its own (hevr serve's render): cancellable alone
    if job is None:
        return _compute(list(tasks), client, progress, desc, keep, on_result, steps, unit, None)
    job.check()
    try:
        return _compute(list(tasks), client, progress, desc, keep, on_result, steps, unit, job)
    except Exception:
        if job.cancelled:  # the futures' cancellation, a task that found the job cancelled
            raise cancel.Cancelled(f"cancelled: {job.reason}") from None
        raise


def _compute(
    tasks: list[Any],
    client: Any,
    progress: bool,
    desc: str,
    keep: int,
    on_result: Callable[[int, Any], None] | None,
    steps: int,
    unit: str,
    job: Any,
) -> list[Any]:
    """:func:`compute`'s work; ``job`` (a :class:`hevr.runtime.cancel.Scope` or None) cancels its futures."""
    if not tasks:
        return []
    client = active_client(client)
    t0 = time.perf_counter()
    if client is not None:
        futures = client.compute(tasks)
        undo = job.on_cancel(lambda: client.cancel(futures)) if job is not None else (lambda: None)
        bar = Progress(len(futures), desc, progress, steps=steps, unit=unit)
        if steps:
            client.subscribe_topic(cancel.TOPIC, lambda event: bar.step(int(event[1])))
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
            undo()
            if steps:
                with contextlib.suppress(Exception):  # a client closing after an interrupt
                    client.unsubscribe_topic(cancel.TOPIC)
                if not failed and all(f.status == "finished" for f in futures):
                    bar.step(max(0, steps - bar.steps_done))  # the last events may still be on their way
            bar.close(failed=failed)
        rest = [i for i in range(cut) if i not in got]
        got.update(zip(rest, client.gather([futures[i] for i in rest])))
        results = [got[i] for i in range(cut)] + list(futures[cut:])
    else:
        bar = Progress(0, desc, progress, steps=steps, unit=unit)  # the callback learns the number of graph tasks
        with TaskCounter(bar), cancel.counting(bar.step):
            results = _compute_local(tasks, job)
        if on_result is not None:
            for i, value in enumerate(results[: len(results) - keep] if keep else results):
                on_result(i, value)
    log.info(
        "%s: %d tasks in %.2f s (%s)",
        desc,
        len(tasks),
        time.perf_counter() - t0,
        "distributed" if client is not None else "default scheduler",
    )
    return results


class _JobPool(ThreadPoolExecutor):
    """The threaded scheduler's pool for a cancellable job: a task submitted after the job's
    cancellation raises :class:`hevr.runtime.cancel.Cancelled` instead of running (dask then raises it)."""

    def __init__(self, max_workers: int, job: Any) -> None:
        super().__init__(max_workers=max_workers)
        self.job = job

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        def run() -> Any:
            self.job.check()
            return fn(*args, **kwargs)

        return super().submit(run)


def _compute_local(tasks: list[Any], job: Any = None) -> list[Any]:
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
    pool = ThreadPoolExecutor(max_workers=workers) if job is None else _JobPool(workers, job)
    cancel.clear()
    try:
        return list(dask.compute(*tasks, pool=pool))
    except KeyboardInterrupt:  # Ctrl-C: the running tasks stop at their next check, not at their end
        cancel.stop()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
