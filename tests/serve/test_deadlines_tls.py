"""``hevr serve`` over TLS gives back the open files of the connections it closes (issue 48, the second
review): a TLS connection the guard closed left its bounds at once but, closed politely, kept its socket
until the peer's close_notify (30 s on Python 3.11, for ever on 3.10), so one address could hold far more
descriptors than ``per-address``. The guard now aborts what it closes over TLS."""

from __future__ import annotations

import os
import ssl
import sys
import time

import pytest
from test_deadlines import ENV, IDLE, SLACK, _open, _pems

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="127.0.0.x sources and /proc: Linux")


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def test_tls_connections_the_guard_closes_give_back_their_sockets(served_store, tmp_path):
    from _serving import hevr_serve

    _pems(tmp_path)
    with hevr_serve(
        str(served_store.dir / "v.zarr"),
        "--tls-cert",
        str(tmp_path / "cert.pem"),
        "--tls-key",
        str(tmp_path / "key.pem"),
        env=ENV,
    ) as (url, proc, lines):
        context = ssl.create_default_context(cafile=str(tmp_path / "ca.pem"))
        time.sleep(1.0)
        before = _fds(proc.pid)
        held = []
        for _ in range(20):  # handshakes done, then never a byte and never a close of our own
            s = _open(url, "127.0.0.30")
            s.setblocking(True)
            held.append(context.wrap_socket(s, server_hostname="127.0.0.1"))
        t0 = time.monotonic()
        while time.monotonic() - t0 < IDLE + SLACK and _fds(proc.pid) > before + 2:
            time.sleep(0.1)
        after = _fds(proc.pid)
        for s in held:
            s.close()
    assert after <= before + 2, (before, after)  # polite closes held 20 sockets here for 30 s
