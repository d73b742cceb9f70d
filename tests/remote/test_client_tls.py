"""A TLS failure says what to do (issue 48, item 7): a certificate this process does not trust says
``pass --cafile``; ``http://`` to a TLS port says ``use https://``; ``https://`` to a plain port
says ``use http://``. In-process servers on 127.0.0.1 with a throw-away CA (trustme)."""

from __future__ import annotations

import socket
import ssl
import threading

import pytest

import hevr
from hevr.remote import connect

trustme = pytest.importorskip("trustme")


def listen(handle):
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)

    def accept():
        while True:
            try:
                conn, _ = sock.accept()
            except OSError:
                return
            threading.Thread(target=handle, args=(conn,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    return sock, sock.getsockname()[1]


ANSWER = (
    b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 14\r\nConnection: close\r\n\r\n"
    b'{"stores": []}'
)


@pytest.fixture(scope="module")
def servers(tmp_path_factory):
    ca = trustme.CA()
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ca.issue_cert("127.0.0.1").configure_cert(ctx)
    cafile = tmp_path_factory.mktemp("tls") / "ca.pem"
    ca.cert_pem.write_to_path(str(cafile))

    def tls(conn):
        try:
            with ctx.wrap_socket(conn, server_side=True) as s:
                s.settimeout(10)
                s.recv(65536)
                s.sendall(ANSWER)
        except OSError:
            conn.close()

    def plain(conn):
        with conn:
            try:
                conn.settimeout(10)
                conn.recv(65536)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
            except OSError:
                pass

    a, tls_port = listen(tls)
    b, plain_port = listen(plain)
    yield tls_port, plain_port, str(cafile)
    a.close()
    b.close()


def test_tls_with_the_ca_works(servers):
    tls_port, _, cafile = servers
    assert connect(f"https://127.0.0.1:{tls_port}", cafile=cafile, timeout=10).stores() == []


def test_an_untrusted_certificate_says_pass_cafile(servers):
    tls_port, _, _ = servers
    with pytest.raises(hevr.RemoteConnectError, match="certificate is not trusted.*pass --cafile PEM"):
        connect(f"https://127.0.0.1:{tls_port}", timeout=10).stores()


def test_the_wrong_scheme_says_which(servers):
    tls_port, plain_port, _ = servers
    with pytest.raises(hevr.RemoteConnectError, match=f"speaks TLS on port {tls_port}: use https://127.0.0.1"):
        connect(f"http://127.0.0.1:{tls_port}", timeout=10).stores()
    with pytest.raises(hevr.RemoteConnectError, match=f"plain HTTP on port {plain_port}: use http://127.0.0.1"):
        connect(f"https://127.0.0.1:{plain_port}", timeout=10).stores()


def test_nobody_listening_is_a_connect_error():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    for scheme in ("http", "https"):
        with pytest.raises(hevr.RemoteConnectError, match="is the server up") as e:
            connect(f"{scheme}://127.0.0.1:{port}", timeout=10).stores()
        assert "use http" not in str(e.value)
