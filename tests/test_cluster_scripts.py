"""The deployment files in cluster/: launch.py runs, dask.yaml only sets real config keys."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CLUSTER = ROOT / "cluster"
LAUNCH = CLUSTER / "launch.py"
DASK_YAML = CLUSTER / "dask.yaml"


def _env(**extra: str) -> dict[str, str]:
    """The current environment without DASK_* overrides (they would beat dask.yaml)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    env["PYTHONUNBUFFERED"] = "1"
    env.update(extra)
    return env


def _leaf_keys(user: dict, defaults: dict, prefix: str = "") -> list[tuple[str, object]]:
    """Dotted keys set by ``user``; fails on a key that has no default."""
    out = []
    for key, value in user.items():
        dotted = f"{prefix}{key}"
        assert key in defaults, f"cluster/dask.yaml sets {dotted!r}, which is not a Dask/distributed config key"
        default = defaults[key]
        if isinstance(value, dict) and isinstance(default, dict) and default:
            out.extend(_leaf_keys(value, default, dotted + "."))
        else:
            out.append((dotted, value))
    return out


def _dask_defaults() -> dict:
    import dask.config
    import distributed  # noqa: F401  (registers distributed's defaults)

    return dask.config.merge(*dask.config.defaults)


def test_launch_help():
    res = subprocess.run(
        [sys.executable, str(LAUNCH), "--help"], capture_output=True, text=True, timeout=30, env=_env()
    )
    assert res.returncode == 0, res.stderr
    for flag in ("--workers", "--memory-limit", "--dashboard-port", "--scheduler-only", "--check"):
        assert flag in res.stdout
    assert "examples:" in res.stdout


def test_launch_import_starts_nothing():
    run = f"runpy.run_path({str(LAUNCH)!r}, run_name='not_main')"
    code = f"import runpy, threading; {run}; print(threading.active_count())"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30, env=_env())
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "1"  # no cluster, no event-loop thread


def test_launch_rejects_bad_arguments():
    for bad in (
        ["--workers", "0"],
        ["--memory-limit", "lots"],
        ["--port", "70000"],
        ["--scheduler-only", "--check", "tcp://x:1"],
    ):
        res = subprocess.run(
            [sys.executable, str(LAUNCH), *bad], capture_output=True, text=True, timeout=30, env=_env()
        )
        assert res.returncode == 2, (bad, res.stderr)


def test_dask_yaml_keys_exist():
    user = yaml.safe_load(DASK_YAML.read_text())
    assert isinstance(user, dict) and user
    keys = _leaf_keys(user, _dask_defaults())
    assert "distributed.scheduler.allowed-failures" in dict(keys)
    assert "distributed.worker.memory.spill" in dict(keys)


def test_dask_yaml_matches_schema():
    jsonschema = pytest.importorskip("jsonschema")
    import dask
    import distributed

    user = yaml.safe_load(DASK_YAML.read_text())
    dask_schema = yaml.safe_load((Path(dask.__file__).parent / "dask-schema.yaml").read_text())
    dist_schema = yaml.safe_load((Path(distributed.__file__).parent / "distributed-schema.yaml").read_text())
    # dask's schema does not cover the distributed section; graft distributed's in
    dask_schema["properties"]["distributed"] = dist_schema["properties"]["distributed"]
    jsonschema.validate(user, dask_schema)


def test_dask_yaml_is_picked_up_via_dask_config(tmp_path):
    """DASK_CONFIG=cluster/ really applies every value (as the README tells users)."""
    user = yaml.safe_load(DASK_YAML.read_text())
    keys = [k for k, _ in _leaf_keys(user, _dask_defaults())]
    code = (
        "import json, sys, dask, distributed; "
        "print(json.dumps({k: dask.config.get(k) for k in json.loads(sys.argv[1])}))"
    )
    res = subprocess.run(
        [sys.executable, "-c", code, json.dumps(keys)],
        capture_output=True,
        text=True,
        timeout=30,
        env=_env(DASK_CONFIG=str(CLUSTER), HOME=str(tmp_path)),
    )
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout)
    expected = dict(_leaf_keys(user, _dask_defaults()))
    assert got == json.loads(json.dumps(expected))


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _reader(stream, q: queue.Queue[str | None]) -> None:
    for line in iter(stream.readline, ""):
        q.put(line)
    q.put(None)


def _launch(*args: str, port: int):
    """Start cluster/launch.py on ``port`` (1 GiB workers, dashboard on a free port): the process and
    queues of its stdout and stderr lines (None at the end)."""
    proc = subprocess.Popen(
        [sys.executable, str(LAUNCH), *args, "--port", str(port), "--dashboard-port", "0", "--memory-limit", "1GiB"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        cwd=str(ROOT),
    )
    lines: queue.Queue = queue.Queue()
    errs: queue.Queue = queue.Queue()
    for stream, q in ((proc.stdout, lines), (proc.stderr, errs)):
        threading.Thread(target=_reader, args=(stream, q), daemon=True).start()
    return proc, lines, errs


@pytest.mark.timeout(60)
def test_launch_local_cluster_one_worker():
    from distributed import Client

    t0 = time.monotonic()
    port = _free_port()
    proc, lines, errs = _launch("--workers", "1", port=port)
    try:
        address = None
        deadline = time.monotonic() + 20
        seen = []
        while address is None and time.monotonic() < deadline:
            try:
                line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            except queue.Empty:
                break
            if line is None:
                break
            seen.append(line)
            m = re.match(r"Scheduler address:\s*(\S+)", line)
            if m:
                address = m.group(1)
        assert address, f"no address printed; stdout={seen!r} stderr={list(errs.queue)!r}"
        assert address == f"tcp://127.0.0.1:{port}"

        with Client(address, timeout=10, set_as_default=False) as client:
            client.wait_for_workers(1, timeout=15)
            try:
                workers = client.scheduler_info(n_workers=-1)["workers"]
            except TypeError:  # distributed < 2025 has no n_workers argument
                workers = client.scheduler_info()["workers"]
            assert len(workers) == 1
            (w,) = workers.values()
            assert w["nthreads"] == 1
            assert w["memory_limit"] == 2**30
            assert client.submit(sum, [1, 2, 3], pure=False).result(timeout=10) == 6

        check = subprocess.run(
            [sys.executable, str(LAUNCH), "--check", address, "--timeout", "5"],
            capture_output=True,
            text=True,
            timeout=20,
            env=_env(),
        )
        assert check.returncode == 0, check.stderr
        assert "Workers:   1   threads: 1" in check.stdout

        if sys.platform != "win32":
            proc.send_signal(signal.SIGTERM)  # handled like Ctrl-C: close the cluster, exit 0
            assert proc.wait(timeout=15) == 0
            rest = []
            while (line := lines.get(timeout=5)) is not None:
                rest.append(line)
            assert any("Stopped." in line for line in rest), rest
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert time.monotonic() - t0 < 30


@pytest.mark.timeout(60)
def test_launch_gpus_one_worker_per_device():
    """--gpus 2 (dask-cuda not installed here): two Nanny workers, 1 thread each, worker i started
    with CUDA_VISIBLE_DEVICES=i — no GPU is needed to check the recipe."""
    from distributed import Client

    port = _free_port()
    proc, lines, _ = _launch("--gpus", "2", port=port)
    try:
        seen, deadline = [], time.monotonic() + 30
        while time.monotonic() < deadline and not any("Scheduler address:" in line for line in seen):
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            if line is None:
                break
            seen.append(line)
        assert any("2 GPU worker process(es), worker i on CUDA device i" in line for line in seen), seen
        with Client(f"tcp://127.0.0.1:{port}", timeout=10, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=20)
            got = client.run(os.getenv, "CUDA_VISIBLE_DEVICES")
            assert sorted(got.values()) == ["0", "1"]
            assert {w["nthreads"] for w in client.scheduler_info()["workers"].values()} == {1}
        if sys.platform != "win32":
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
