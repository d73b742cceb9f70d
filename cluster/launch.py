#!/usr/bin/env python
"""Start (or check) a Dask cluster for hevr.

This is a deployment script, not library code: hevr itself never starts a cluster, it
uses the active ``distributed`` client. The script only needs dask and distributed, so
it can be copied to any machine that has them.

Modes
-----
* default           a LocalCluster on this machine: ``--workers`` processes with
                    ``--threads-per-worker`` threads each (default 1, because gmpy2's
                    big-integer arithmetic holds the GIL: more threads add no speed),
                    kept running until Ctrl-C / SIGTERM.
* --scheduler-only  only a scheduler; start workers on other hosts with
                    ``dask worker tcp://HOST:PORT --nworkers N --nthreads 1``.
* --check ADDRESS   connect to a running scheduler and list its workers.
* --gpus N          one worker process per GPU for hevr's ``cuda`` backend: dask-cuda's
                    LocalCUDACluster where it is installed, else N Nanny workers, worker i started
                    with ``CUDA_VISIBLE_DEVICES=i`` (1 thread each). Render with ``backend="cuda"``.

Settings from ``cluster/dask.yaml`` apply when the script is started with
``DASK_CONFIG=cluster/`` (LocalCluster passes its configuration on to the workers).
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import signal
import sys
from typing import Any

EXAMPLES = """\
examples:
  # a laptop: 2 worker processes x 1 thread, 4 GiB each, dashboard on :8787
  python cluster/launch.py --workers 2
  DASK_CONFIG=cluster/ python cluster/launch.py --workers 4 --memory-limit 8GiB

  # then, in another shell (the address is printed at start-up)
  hevr render vol.zarr --scheduler tcp://127.0.0.1:8786
  python -c 'from distributed import Client; import hevr; c = Client("tcp://127.0.0.1:8786"); ...'

  # many machines: a scheduler reachable from the other hosts ...
  python cluster/launch.py --scheduler-only --port 8786
  # ... and on every worker host
  dask worker tcp://SCHEDULER-HOST:8786 --nworkers 8 --nthreads 1 --memory-limit 4GiB

  # a GPU machine: one worker per GPU (hevr.render(..., backend="cuda"); prove it with hevr bench --gpu)
  python cluster/launch.py --gpus 4 --memory-limit 32GiB

  # is the cluster up, and how many workers / threads / memory does it have?
  python cluster/launch.py --check tcp://SCHEDULER-HOST:8786

  # TLS between client, scheduler and workers (see cluster/README.md)
  python cluster/launch.py --scheduler-only --tls-ca-file ca.pem --tls-cert sched.pem --tls-key sched.key
"""


# ----------------------------------------------------------------------------------------
# argument handling
# ----------------------------------------------------------------------------------------
def _memory_limit(text: str) -> str:
    """Validate --memory-limit early: 'auto', '0' (no limit), a fraction, or bytes like 4GiB."""
    from dask.utils import parse_bytes

    value = text.strip()
    if value.lower() == "auto":
        return "auto"
    try:
        number = float(value)
    except ValueError:
        try:
            if parse_bytes(value) <= 0:
                raise ValueError
        except (ValueError, TypeError):
            raise argparse.ArgumentTypeError(
                f"expected 'auto', 0, a fraction of system memory or a size like 4GiB, got {text!r}"
            ) from None
        return value
    if number < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative memory limit, got {text!r}")
    return value


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port in [0, 65535] (0 = random), got {port}")
    return port


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python cluster/launch.py",
        description="Start a Dask cluster for hevr (LocalCluster or scheduler only), or check a running one.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--scheduler-only", action="store_true",
                      help="start only a scheduler (workers join with 'dask worker ADDRESS')")
    mode.add_argument("--check", metavar="ADDRESS",
                      help="connect to the scheduler at ADDRESS (e.g. tcp://host:8786), list its workers and exit")

    local = p.add_argument_group("LocalCluster")
    local.add_argument("--workers", type=_positive_int, default=2, metavar="N",
                       help="number of worker processes (default: 2)")
    local.add_argument("--threads-per-worker", type=_positive_int, default=1, metavar="T",
                       help="threads per worker process (default: 1; gmpy2 holds the GIL, add processes instead)")
    local.add_argument("--memory-limit", type=_memory_limit, default="4GiB", metavar="SIZE",
                       help="memory limit per worker process: a size like 4GiB, a fraction of system "
                            "memory, 'auto' or 0 for no limit (default: 4GiB)")
    local.add_argument("--gpus", type=_positive_int, metavar="N",
                       help="one worker process per GPU, worker i on GPU i (CUDA_VISIBLE_DEVICES); replaces --workers")
    local.add_argument("--local-directory", metavar="DIR",
                       help="directory for worker spill files (default: the system temp directory)")

    net = p.add_argument_group("network")
    net.add_argument("--host", default=None,
                     help="interface/IP the scheduler listens on (default: 127.0.0.1 for a LocalCluster, "
                          "all interfaces with --scheduler-only)")
    net.add_argument("--port", type=_port, default=8786,
                     help="scheduler port (default: 8786; 0 = a random free port)")
    net.add_argument("--dashboard-port", type=_port, default=8787,
                     help="dashboard port (default: 8787; 0 = a random free port)")
    net.add_argument("--no-dashboard", action="store_true", help="do not start the dashboard")
    net.add_argument("--scheduler-file", metavar="FILE",
                     help="write the scheduler's connection information to FILE (JSON); workers on a shared "
                          "filesystem can then join with 'dask worker --scheduler-file FILE'")
    net.add_argument("--timeout", type=float, default=10.0, metavar="SECONDS",
                     help="connection timeout for --check (default: 10)")

    tls = p.add_argument_group("TLS (switches the protocol to tls://)")
    tls.add_argument("--tls-ca-file", metavar="PEM", help="CA certificate(s) used to verify the peers")
    tls.add_argument("--tls-cert", metavar="PEM", help="certificate of this process (scheduler, or client with --check)")
    tls.add_argument("--tls-key", metavar="PEM", help="private TLS key of this process (not a Paillier key!)")
    return p


# ----------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------
def _security(args: argparse.Namespace, role: str) -> Any:
    """A distributed.Security for ``role`` ('scheduler', 'client' or 'all'), or None without TLS flags."""
    if not (args.tls_ca_file or args.tls_cert or args.tls_key):
        return None
    if not (args.tls_ca_file and args.tls_cert and args.tls_key):
        raise SystemExit("launch.py: error: TLS needs all of --tls-ca-file, --tls-cert and --tls-key")
    from distributed import Security

    roles = ("scheduler", "worker", "client") if role == "all" else (role,)
    kwargs: dict[str, Any] = {"tls_ca_file": args.tls_ca_file, "require_encryption": True}
    for r in roles:
        kwargs[f"tls_{r}_cert"] = args.tls_cert
        kwargs[f"tls_{r}_key"] = args.tls_key
    return Security(**kwargs)


def _dashboard_address(args: argparse.Namespace, host: str | None) -> str | None:
    if args.no_dashboard:
        return None
    return f"{host}:{args.dashboard_port}" if host else f":{args.dashboard_port}"


def _say(*lines: str) -> None:
    for line in lines:
        print(line, flush=True)


def _bokeh_note() -> list[str]:
    if importlib.util.find_spec("bokeh") is None:
        return ["  (the dashboard pages need bokeh: pip install bokeh)"]
    return []


async def _wait_for_stop() -> None:
    """Block until SIGINT (Ctrl-C) or SIGTERM."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError, ValueError):  # pragma: no cover - Windows
            pass  # Ctrl-C then arrives as KeyboardInterrupt; asyncio.run cancels us and we clean up
    await stop.wait()


# ----------------------------------------------------------------------------------------
# modes
# ----------------------------------------------------------------------------------------
async def run_local_cluster(args: argparse.Namespace) -> int:
    from dask.utils import format_bytes, parse_bytes
    from distributed import LocalCluster

    host = args.host or "127.0.0.1"
    security = _security(args, "all")
    kwargs: dict[str, Any] = dict(
        n_workers=args.workers,
        threads_per_worker=args.threads_per_worker,
        processes=True,
        memory_limit=args.memory_limit,
        host=host,
        scheduler_port=args.port,
        dashboard_address=_dashboard_address(args, host),
        asynchronous=True,
    )
    if args.local_directory:
        kwargs["local_directory"] = args.local_directory
    if args.scheduler_file:
        kwargs["scheduler_kwargs"] = {"scheduler_file": args.scheduler_file}
    if security is not None:
        kwargs.update(security=security, protocol="tls://")
    try:
        mem = format_bytes(parse_bytes(args.memory_limit))
    except (ValueError, TypeError):
        mem = args.memory_limit

    async with _gpu_cluster(args, kwargs) if args.gpus else LocalCluster(**kwargs) as cluster:
        address = cluster.scheduler_address
        link = None if args.no_dashboard else cluster.dashboard_link
        what = (f"{args.gpus} GPU worker process(es), worker i on CUDA device i, 1 thread each" if args.gpus else
                f"{args.workers} worker process(es) x {args.threads_per_worker} thread(s)")
        _say(
            f"hevr LocalCluster: {what}, memory limit {mem} each",
            f"Scheduler address: {address}",
            f"Dashboard:         {link or 'disabled'}",
            *(_bokeh_note() if link else []),
            "Connect with:",
            f"  hevr render vol.zarr --scheduler {address}",
            f"  python: from distributed import Client; client = Client({address!r})",
            "Press Ctrl-C to stop.",
        )
        await _wait_for_stop()
        _say("Stopping the cluster ...")
    _say("Stopped.")
    return 0


def _gpu_cluster(args: argparse.Namespace, kwargs: dict) -> Any:
    """One worker per GPU: dask-cuda's LocalCUDACluster if installed, else a SpecCluster of Nanny
    workers, worker i started with CUDA_VISIBLE_DEVICES=i (what LocalCUDACluster does too)."""
    if importlib.util.find_spec("dask_cuda") is not None:
        from dask_cuda import LocalCUDACluster

        return LocalCUDACluster(CUDA_VISIBLE_DEVICES=list(range(args.gpus)), threads_per_worker=1,
                                **{k: v for k, v in kwargs.items() if k not in ("n_workers", "threads_per_worker",
                                                                               "processes")})
    from distributed import Nanny, Scheduler, SpecCluster

    scheduler = {"cls": Scheduler, "options": {"host": kwargs["host"], "port": kwargs["scheduler_port"],
                                               "dashboard_address": kwargs["dashboard_address"],
                                               **kwargs.get("scheduler_kwargs", {}),
                                               **({"protocol": kwargs["protocol"]} if "protocol" in kwargs else {}),
                                               **({"security": kwargs["security"]} if "security" in kwargs else {})}}
    options = {"nthreads": 1, "memory_limit": kwargs["memory_limit"], "host": kwargs["host"],
               **({"local_directory": kwargs["local_directory"]} if "local_directory" in kwargs else {}),
               **({"security": kwargs["security"]} if "security" in kwargs else {})}
    workers = {f"gpu-{i}": {"cls": Nanny, "options": {**options, "name": f"gpu-{i}",
                                                      "env": {"CUDA_VISIBLE_DEVICES": str(i)}}}
               for i in range(args.gpus)}
    return SpecCluster(workers=workers, scheduler=scheduler, asynchronous=True, security=kwargs.get("security"))


async def run_scheduler(args: argparse.Namespace) -> int:
    from distributed import Scheduler
    from distributed.comm import get_address_host
    from distributed.utils import format_dashboard_link

    security = _security(args, "scheduler")
    kwargs: dict[str, Any] = dict(
        host=args.host or None,  # None: listen on all interfaces, advertise this host's IP
        port=args.port,
        dashboard=not args.no_dashboard,
        dashboard_address=_dashboard_address(args, args.host),
        scheduler_file=args.scheduler_file,
    )
    if security is not None:
        kwargs.update(security=security, protocol="tls")
    async with Scheduler(**kwargs) as scheduler:
        address = scheduler.address
        link = None
        if not args.no_dashboard and scheduler.http_server is not None:
            link = format_dashboard_link(get_address_host(address), scheduler.http_server.port)
        tls = " --tls-ca-file ca.pem --tls-cert worker.pem --tls-key worker.key" if security else ""
        _say(
            "hevr scheduler (no workers yet)",
            f"Scheduler address: {address}",
            f"Dashboard:         {link or 'disabled'}",
            *(_bokeh_note() if link else []),
            "Start workers on each host with:",
            f"  dask worker {address} --nworkers N --nthreads 1 --memory-limit 4GiB{tls}",
            "Press Ctrl-C to stop.",
        )
        await _wait_for_stop()
        _say("Stopping the scheduler ...")
    _say("Stopped.")
    return 0


PACKAGES = ("dask", "distributed", "hevr", "gmpy2", "zarr", "numpy")


def run_check(args: argparse.Namespace) -> int:
    from dask.utils import format_bytes
    from distributed import Client

    security = _security(args, "client")
    if args.check.startswith("tls://") and security is None:
        import dask

        if not dask.config.get("distributed.comm.tls.ca-file", None):
            print("launch.py: a tls:// address needs --tls-ca-file, --tls-cert and --tls-key "
                  "(or the distributed.comm.tls settings in the Dask config)", file=sys.stderr)
            return 1
    try:
        client = Client(args.check, timeout=args.timeout, security=security, set_as_default=False)
    except Exception as exc:  # OSError, TimeoutError, ValueError for a malformed address
        print(f"launch.py: cannot connect to {args.check}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    try:
        try:
            info = client.scheduler_info(n_workers=-1)
        except TypeError:  # distributed < 2025: no n_workers argument, always all workers
            info = client.scheduler_info()
        workers = info.get("workers", {})
        versions: dict[str, Any] = {}
        try:
            versions = client.get_versions(packages=list(PACKAGES))
        except Exception as exc:  # a worker without hevr must not break the check
            print(f"launch.py: could not collect package versions: {exc}", file=sys.stderr)

        total_threads = sum(int(w.get("nthreads", 0)) for w in workers.values())
        total_mem = sum(int(w.get("memory_limit") or 0) for w in workers.values())
        _say(
            f"Scheduler: {info.get('address', args.check)}",
            f"Dashboard: {client.dashboard_link}",
            f"Workers:   {len(workers)}   threads: {total_threads}   memory: {format_bytes(total_mem)}",
        )
        client_pkgs = versions.get("client", {}).get("packages", {})
        worker_pkgs = versions.get("workers", {})
        problems: list[str] = []
        for addr in sorted(workers):
            w = workers[addr]
            mem = int(w.get("memory_limit") or 0)
            pkgs = (worker_pkgs.get(addr) or {}).get("packages", {})
            pv = " ".join(f"{k}={pkgs.get(k)}" for k in ("hevr", "gmpy2") if k in pkgs)
            _say(f"  {addr}  name={w.get('name')}  threads={w.get('nthreads')}  "
                 f"memory={format_bytes(mem) if mem else 'unlimited'}  {pv}".rstrip())
            if int(w.get("nthreads", 1)) > 1:
                problems.append(f"{addr} runs {w.get('nthreads')} threads; gmpy2 holds the GIL, "
                                "prefer --nthreads 1 with more --nworkers")
            if pkgs and pkgs.get("hevr") is None:
                problems.append(f"{addr} cannot import hevr; install it on every worker host")
            for name in ("dask", "distributed", "hevr"):
                if pkgs.get(name) and client_pkgs.get(name) and pkgs[name] != client_pkgs[name]:
                    problems.append(f"{addr} has {name} {pkgs[name]}, this client has {client_pkgs[name]}")
        for line in problems:
            print(f"warning: {line}", file=sys.stderr)
        if not workers:
            print("launch.py: the scheduler has no workers", file=sys.stderr)
            return 1
        return 0
    finally:
        client.close()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.check:
        return run_check(args)
    runner = run_scheduler if args.scheduler_only else run_local_cluster
    try:
        return asyncio.run(runner(args))
    except KeyboardInterrupt:  # pragma: no cover - platforms without loop signal handlers
        return 0
    except OSError as exc:  # e.g. the port is taken
        print(f"launch.py: cannot start: {exc} (try another --port / --dashboard-port, or 0)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
