"""Starting a real ``hevr serve`` process for the tests (on 127.0.0.1, an ephemeral port)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

HEVR = [sys.executable, "-m", "hevr"]
_URL = re.compile(r"serving: (https?://\S+)")


@contextmanager
def hevr_serve(
    *args: str, timeout: float = 90.0, env: dict | None = None, cwd: str | Path | None = None, port: int = 0
):
    """``hevr serve ARGS --port PORT`` (default 0: an ephemeral one) as a subprocess; yields (url,
    process, lines printed so far)."""
    proc = subprocess.Popen(
        [*HEVR, "serve", *args, "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
        cwd=cwd,
        start_new_session=True,
    )
    lines: list[str] = []
    url: list[str] = []
    ready = threading.Event()

    def pump() -> None:
        for line in proc.stdout:  # type: ignore[union-attr]
            lines.append(line.rstrip("\n"))
            m = _URL.search(line)
            if m and not url:
                url.append(m.group(1))
                ready.set()
        ready.set()

    threading.Thread(target=pump, daemon=True).start()
    try:
        if not ready.wait(timeout) or not url:
            raise RuntimeError("hevr serve did not start:\n" + "\n".join(lines[-40:]))
        yield url[0], proc, lines
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def wait_until(predicate, timeout: float = 10.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if predicate():
            return True
        time.sleep(0.05)
    return False


def refuse_unpickling(monkeypatch) -> list:
    """Make every unpickling (and every new ``distributed.Client``) in this process fail; returns the
    list that records each attempt (a test asserts it stays empty)."""
    import pickle

    import distributed

    attempts: list = []

    def refuse(*a, **k):
        attempts.append(True)
        raise AssertionError("the key holder's process unpickled or made a Dask client")

    class NoUnpickler:
        def __init__(self, *a, **k):
            refuse()

    monkeypatch.setattr(pickle, "loads", refuse)
    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "Unpickler", NoUnpickler)
    monkeypatch.setattr(distributed.Client, "__init__", refuse)
    return attempts
