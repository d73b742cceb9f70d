"""The key holder's deadline covers the whole exchange (issue 48): a server on 127.0.0.1 that sends
its status line and headers one byte a second never trips a per-read timeout, yet
``hevr.connect(url, timeout=2)``, a render and ``hevr render --server --timeout 3`` give up at the
deadline with :class:`hevr.RemoteTimeoutError`; a TLS handshake that never ends is bounded by
``connect_timeout``."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

import hevr
from hevr.cli.main import main
from hevr.remote import connect

SLACK = 8.0  # a loaded machine: generous, never a speed assert


class Dribbler:
    """A raw HTTP server: ``honest[path_suffix]`` answers at once, anything else is answered one
    byte every ``interval`` seconds (a valid 200 answer, had it time to finish)."""

    def __init__(self, honest=None, interval=1.0):
        self.honest = honest or {}
        self.interval = interval
        self.stop = threading.Event()
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn):
        with conn:
            try:
                head = b""
                while b"\r\n\r\n" not in head:
                    got = conn.recv(4096)
                    if not got:
                        return
                    head += got
                path = head.split(b" ", 2)[1].decode()
                body = next((b for suffix, b in self.honest.items() if path.endswith(suffix)), None)
                if body is not None:
                    conn.sendall(
                        b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: "
                        + str(len(body)).encode()
                        + b"\r\nConnection: close\r\n\r\n"
                        + body
                    )
                    return
                answer = (
                    b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nX-Pad: "
                    + b"a" * 200
                    + b'\r\nContent-Length: 14\r\n\r\n{"stores": []}'
                )
                for i in range(len(answer)):
                    if self.stop.wait(self.interval):
                        return
                    conn.sendall(answer[i : i + 1])
            except OSError:
                return

    def close(self):
        self.stop.set()
        self.sock.close()


@pytest.fixture
def dribbler():
    servers = []

    def make(**kw):
        servers.append(Dribbler(**kw))
        return servers[-1]

    yield make
    for s in servers:
        s.close()


def test_a_dribbled_head_hits_the_deadline(dribbler):
    d = dribbler()
    t0 = time.monotonic()
    with pytest.raises(hevr.RemoteTimeoutError, match="timeout: expected an answer within 2 s, got none") as e:
        connect(d.url, timeout=2).stores()
    took = time.monotonic() - t0
    assert 1.5 <= took < 2 + SLACK, took
    assert isinstance(e.value, TimeoutError) and e.value.status is None


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256):
    _, priv = keypair256
    ev = hevr.encrypt_volume(
        hevr.phantom(8), str(tmp_path_factory.mktemp("dl") / "v.zarr"), priv, brick=4, progress=False
    )
    return ev, json.dumps({"id": ev.meta.store_id, "metadata": ev.meta.to_dict()}).encode()


def test_a_dribbled_render_hits_the_deadline(dribbler, store):
    ev, desc = store
    d = dribbler(honest={f"/v1/stores/{ev.meta.store_id}": desc})
    rv = connect(d.url, timeout=2).open(ev.meta.store_id)
    t0 = time.monotonic()
    with pytest.raises(hevr.RemoteTimeoutError, match="/render: timeout: expected an answer within 2 s"):
        hevr.render(rv, hevr.Camera.orbit(rv, width=6, height=5), progress=False, verify=False)
    assert time.monotonic() - t0 < 2 + SLACK


def test_the_cli_gives_up_at_its_timeout(dribbler, store, tmp_path, capsys):
    ev, _ = store
    d = dribbler()
    out = tmp_path / "f.hevr"
    t0 = time.monotonic()
    code = main(
        ["render", "--server", d.url, ev.meta.store_id, "--out", str(out), "--size", "6x5", "--timeout", "3", "-q"]
    )
    took = time.monotonic() - t0
    assert code == 1 and not out.exists()
    assert "timeout: expected an answer within 3 s" in capsys.readouterr().err
    assert took < 3 + SLACK, took
    assert main(["render", "--server", d.url, ev.meta.store_id, "--out", str(out), "--connect-timeout", "0"]) == 2
    assert "--connect-timeout: expected seconds" in capsys.readouterr().err


def test_a_tls_handshake_that_never_ends_is_bounded_by_connect_timeout():
    sock = socket.socket()  # accepts (the kernel does) and never says a word
    sock.bind(("127.0.0.1", 0))
    sock.listen(4)
    try:
        t0 = time.monotonic()
        with pytest.raises(hevr.RemoteTimeoutError, match="expected a connection within 1 s"):
            connect(f"https://127.0.0.1:{sock.getsockname()[1]}", timeout=60, connect_timeout=1).stores()
        assert time.monotonic() - t0 < 1 + SLACK
    finally:
        sock.close()
