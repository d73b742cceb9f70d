"""The key holder survives a lying server: a test double on loopback answers with forged,
truncated, oversized, slow, garbage, redirected and compressed-bomb responses; every one ends in a
clean :class:`hevr.RemoteError` within the timeout, and nothing is written."""

from __future__ import annotations

import gzip
import json
import socket
import socketserver
import threading
import time

import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.remote import connect
from hevr.remote.protocol import END, pack_frame


class Double(socketserver.ThreadingTCPServer):
    """An HTTP/1.1 server on 127.0.0.1 whose answers are scripted: ``routes[(method, suffix)]`` is
    a function (body) -> bytes written raw to the socket (status line, headers, body)."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, routes):
        self.routes = routes
        super().__init__(("127.0.0.1", 0), Handler)
        threading.Thread(target=self.serve_forever, daemon=True).start()

    @property
    def url(self):
        return f"http://127.0.0.1:{self.server_address[1]}"


class Handler(socketserver.StreamRequestHandler):
    def handle(self):
        line = self.rfile.readline().decode()
        if not line:
            return
        method, path, _ = line.split(" ", 2)
        length = 0
        while True:
            h = self.rfile.readline().decode()
            if h in ("\r\n", "\n", ""):
                break
            if h.lower().startswith("content-length:"):
                length = int(h.split(":")[1])
        body = self.rfile.read(length) if length else b""
        for (m, suffix), fn in self.server.routes.items():
            if m == method and path.endswith(suffix):
                try:
                    fn(self.wfile, body)
                except (BrokenPipeError, ConnectionResetError):
                    pass
                return
        self.wfile.write(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")


def answer(status=200, media="application/json", body=b"", extra=""):
    def fn(w, _):
        w.write(
            f"HTTP/1.1 {status} X\r\nContent-Type: {media}\r\nContent-Length: {len(body)}\r\n{extra}"
            "Connection: close\r\n\r\n".encode()
            + body
        )

    return fn


@pytest.fixture(scope="module")
def truth(tmp_path_factory, keypair256):
    """A real store and a real image of one camera (what an honest server would send)."""
    pub, priv = keypair256
    d = tmp_path_factory.mktemp("double")
    ev = hevr.encrypt_volume(hevr.phantom(8), str(d / "v.zarr"), priv, brick=4, progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=20, width=9, height=7)
    img = hevr.render(ev, cam, progress=False, verify=False)
    other = hevr.render(ev, hevr.Camera.orbit(ev, azimuth=21, width=9, height=7), progress=False, verify=False)
    desc = json.dumps({"id": ev.meta.store_id, "metadata": ev.meta.to_dict()}).encode()
    return ev, cam, img, other, desc, priv


def _rv(truth, render, timeout=5.0, extra_routes=None):
    ev, _, _, _, desc, _ = truth
    routes = {
        ("GET", f"/v1/stores/{ev.meta.store_id}"): answer(body=desc),
        ("POST", "/render"): render,
        **(extra_routes or {}),
    }
    double = Double(routes)
    return double, connect(double.url, timeout=timeout).open(ev.meta.store_id)


def _expect(truth, render, match, timeout=5.0, cls=hevr.RemoteError):
    double, rv = _rv(truth, render, timeout)
    t0 = time.monotonic()
    try:
        with pytest.raises(cls, match=match):
            hevr.render(rv, truth[1], progress=False, verify=False)
    finally:
        double.shutdown()
    assert time.monotonic() - t0 < timeout + 3


def test_honest_double_gives_the_image(truth):
    double, rv = _rv(truth, answer(media="application/vnd.hevr.image", body=truth[2].to_bytes()))
    img = hevr.render(rv, truth[1], progress=False, verify=False)
    np.testing.assert_array_equal(img.decrypt(truth[5]), truth[2].decrypt(truth[5]))
    double.shutdown()


IMG = "application/vnd.hevr.image"


@pytest.mark.parametrize(
    "name, render, match",
    [
        (
            "another camera's image",
            lambda t: answer(media=IMG, body=t[3].to_bytes()),
            "not the one this request implies",
        ),
        ("truncated", lambda t: answer(media=IMG, body=t[2].to_bytes()[:-40]), "valid .hevr"),
        ("garbage", lambda t: answer(media=IMG, body=bytes(range(256)) * 8), "valid .hevr"),
        (
            "wrong media",
            lambda t: answer(media="application/python-pickle", body=b"\x80\x04N."),
            "expected application",
        ),
        (
            "oversized",
            lambda t: (
                lambda w, _: w.write(
                    f"HTTP/1.1 200 OK\r\nContent-Type: {IMG}\r\nContent-Length: {10**9}\r\n\r\n".encode() + b"\0" * 1000
                )
            ),
            "refused unread",
        ),
        (
            "oversized, chunked",
            lambda t: (
                lambda w, _: (
                    w.write(f"HTTP/1.1 200 OK\r\nContent-Type: {IMG}\r\nTransfer-Encoding: chunked\r\n\r\n".encode()),
                    [w.write(b"10000\r\n" + b"\0" * 65536 + b"\r\n") for _ in range(40)],
                )
            ),
            "at most",
        ),
        ("redirect", lambda t: answer(302, extra="Location: http://evil.example/steal\r\n"), "redirect"),
        (
            "compression bomb",
            lambda t: answer(media=IMG, body=gzip.compress(b"\0" * 50_000_000), extra="Content-Encoding: gzip\r\n"),
            "Content-Encoding",
        ),
        (
            "problem",
            lambda t: answer(
                500,
                "application/problem+json",
                json.dumps({"title": "boom", "status": 500, "detail": "disk on fire"}).encode(),
            ),
            "disk on fire",
        ),
        ("not HTTP", lambda t: lambda w, _: w.write(b"\x00\x01garbage\r\n\r\n"), "^server "),
        ("closed", lambda t: lambda w, _: None, "^server "),
    ],
)
def test_lying_server_gives_a_clean_error(truth, name, render, match):
    """A lie the checks catch is a RemoteAnswerError (issue 48); a server failure, a redirect or a
    connection without an HTTP answer is another RemoteError."""
    lie = name not in ("problem", "redirect", "not HTTP", "closed")
    _expect(truth, render(truth), match, cls=hevr.RemoteAnswerError if lie else hevr.RemoteError)


def test_slow_servers_hit_the_deadline(truth):
    def dribble(w, _):  # headers, then one byte every 0.3 s: never a read timeout, but the deadline
        w.write(f"HTTP/1.1 200 OK\r\nContent-Type: {IMG}\r\nContent-Length: 100000\r\n\r\n".encode())
        w.flush()
        for _ in range(100):
            w.write(b"\0")
            w.flush()
            time.sleep(0.3)

    def silent(w, _):
        time.sleep(8)

    _expect(truth, dribble, "timeout: expected an answer within 2 s", timeout=2.0, cls=hevr.RemoteTimeoutError)
    _expect(truth, silent, "timeout: expected an answer within 2 s", timeout=2.0, cls=hevr.RemoteTimeoutError)


def test_forged_streams_and_aggregates(truth):
    ev, cam, img, _, desc, priv = truth
    W = ev.meta.ciphertext_bytes

    def stream_of(frames):
        body = b"".join(frames)
        return answer(media="application/vnd.hevr.units", body=body)

    cases = [
        ([pack_frame(99, b"\0" * W)], "unit 99"),
        ([pack_frame(0, b"\0" * (W - 1))], "whole"),
        ([pack_frame(END, json.dumps({"ok": True}).encode())], "missing"),
        ([pack_frame(0, b"\0" * W)], "end frame|truncated|expected"),
        ([pack_frame(END, b"not json")], "JSON"),
        ([pack_frame(END, json.dumps({"title": "x", "detail": "render failed"}).encode())], "render failed"),
    ]
    for frames, match in cases:
        ev_, _, _, _, desc_, _ = truth
        double = Double(
            {("GET", f"/v1/stores/{ev.meta.store_id}"): answer(body=desc), ("POST", "/stream"): stream_of(frames)}
        )
        rv = connect(double.url, timeout=5).open(ev.meta.store_id)
        with pytest.raises(hevr.HevrError, match=match):
            hevr.render_frame(rv, cam, priv, progress=False)
        double.shutdown()


def test_bad_store_descriptions(truth):
    ev, _, _, _, desc, _ = truth
    d = json.loads(desc)
    forged = dict(d, metadata=dict(d["metadata"], shape=[9, 9, 9]))  # keyless checksum now wrong
    other = dict(d, id="0" * 16)
    cases = (
        (forged, "checksum"),
        (other, "names the store"),
        ([], "JSON object"),
        # checked by the schema's Store model (hevr.remote.schema), each naming the field
        ({"id": 1}, r"description: expected the fields \['id', 'metadata', 'name'\], missing \['metadata'\]"),
        (dict(d, id=1), r"a store description: id: expected 16 lower-case hex digits, got 1"),
        (dict(d, id="ABCDEF0123456789"), "id: expected 16 lower-case hex digits"),
        (dict(d, colour="red"), r"a store description: expected only the fields .*got extra fields \['colour'\]"),
        (dict(d, metadata=[1]), "metadata: expected"),
        (dict(d, name="a/b"), "name: expected a store name of 1-64"),
        (dict(d, name="0123456789abcdef"), "name: expected a store name that is not 16 hex digits"),
    )
    for doc, match in cases:
        body = json.dumps(doc).encode()
        double = Double({("GET", f"/v1/stores/{ev.meta.store_id}"): answer(body=body)})
        with pytest.raises(hevr.RemoteError, match=match):
            connect(double.url, timeout=5).open(ev.meta.store_id)
        double.shutdown()


def test_store_names_in_descriptions(truth):
    """A description's name (issue 47) is checked; opened by name, the answer must be the store of
    that name, and the volume renders by the id of its checked metadata."""
    ev, _, _, _, desc, _ = truth
    d, sid = json.loads(desc), ev.meta.store_id
    routes = {
        ("GET", "/v1/stores/ct"): answer(body=json.dumps(dict(d, name="ct")).encode()),
        ("GET", "/v1/stores/mr"): answer(body=json.dumps(dict(d, name="ct")).encode()),
        ("GET", "/v1/stores/us"): answer(body=desc),
        ("GET", "/v1/stores/xx"): answer(body=json.dumps(dict(d, name="a/b")).encode()),
        ("GET", "/v1/stores/yy"): answer(body=json.dumps(dict(d, name="0123456789abcdef")).encode()),
        ("GET", "/v1/stores/zz"): answer(body=json.dumps(dict(d, name="zz", extra=1)).encode()),
    }
    double = Double(routes)
    server = connect(double.url, timeout=5)
    rv = server.open("ct")
    assert (rv.name, rv.store_id, rv.path) == ("ct", sid, f"{double.url}/v1/stores/ct")
    for name, match in (
        ("mr", "named 'mr', got one named 'ct'"),
        ("us", "one without a name"),
        ("xx", "name: expected a store name"),
        ("yy", "not 16 hex digits"),
        ("zz", r"expected only the fields .*got extra fields \['extra'\]"),
    ):
        with pytest.raises(hevr.RemoteError, match=match):
            server.open(name)
    double.shutdown()


def test_unreachable_and_bad_arguments():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(hevr.RemoteConnectError, match="ConnectError"):
        connect(f"http://127.0.0.1:{port}", timeout=3).stores()
    for url in ("ftp://x", "http://", "http://u:p@h:1", "http://h/?q=1", 5):
        with pytest.raises(hevr.ParameterError):
            connect(url)
    with pytest.raises(hevr.ParameterError, match="token"):
        connect("http://127.0.0.1:1", token="two words")
    with pytest.raises(hevr.ParameterError, match="timeout"):
        connect("http://127.0.0.1:1", timeout=0)
    assert "tok" not in repr(connect("http://127.0.0.1:1", token="tok-secret"))


def test_cli_writes_nothing_on_a_lie(truth, tmp_path):
    ev, cam, img, other, desc, _ = truth
    double = Double(
        {
            ("GET", f"/v1/stores/{ev.meta.store_id}"): answer(body=desc),
            ("POST", "/render"): answer(media=IMG, body=other.to_bytes()),
        }
    )
    out = tmp_path / "f.hevr"
    code = main(
        [
            "render",
            "--server",
            double.url,
            ev.meta.store_id,
            "--out",
            str(out),
            "--size",
            "9x7",
            "--azimuth",
            "20",
            "--timeout",
            "5",
            "-q",
        ]
    )
    double.shutdown()
    assert code == 1 and not out.exists() and list(tmp_path.iterdir()) == []


def test_review_findings_end_in_remote_errors(truth, keypair256, tmp_path):
    """A Unicode-digit aggregate, a zeroed ciphertext, short or empty streamed units: RemoteError, never
    a raw ValueError or an image holding non-ciphertexts; and a store list over 64 KiB is read."""
    ev, cam, img, _, desc, priv = truth
    W = ev.meta.ciphertext_bytes
    from hevr.image import image_from_bytes

    zeroed = image_from_bytes(img.to_bytes())
    zeroed.ciphertexts[0] = np.zeros_like(zeroed.ciphertexts[0])
    _expect(truth, answer(media=IMG, body=zeroed.to_bytes()), "not a ciphertext", cls=hevr.RemoteAnswerError)

    vev = hevr.encrypt_volume(hevr.phantom(6), str(tmp_path / "t.zarr"), priv, brick=6, verifiable=True, progress=False)
    vcam = hevr.Camera.orbit(vev, width=5, height=4)
    vimg = hevr.render(vev, vcam, progress=False, verify=False)
    vdesc = json.dumps({"id": vev.meta.store_id, "metadata": vev.meta.to_dict()}).encode()
    for agg in ("\u00b2", "1" * 3000, "0", "-5"):
        double = Double(
            {
                ("GET", f"/v1/stores/{vev.meta.store_id}"): answer(body=vdesc),
                ("POST", "/render"): answer(media=IMG, body=vimg.to_bytes()),
                ("POST", "/verify"): answer(body=json.dumps({"aggregate": agg}).encode()),
            }
        )
        rv = connect(double.url, timeout=5).open(vev.meta.store_id)
        with pytest.raises(hevr.RemoteError, match="aggregate"):
            hevr.render(rv, vcam, progress=False)
        double.shutdown()

    for records in (0, 1, 7):
        frames = pack_frame(0, b"\1" * (W * records)) + pack_frame(END, json.dumps({"ok": True}).encode())
        double = Double(
            {
                ("GET", f"/v1/stores/{ev.meta.store_id}"): answer(body=desc),
                ("POST", "/stream"): answer(media="application/vnd.hevr.units", body=frames),
            }
        )
        rv = connect(double.url, timeout=5).open(ev.meta.store_id)
        with pytest.raises(hevr.RemoteError, match="unit 0"):
            hevr.render_frame(rv, cam, priv, progress=False)
        double.shutdown()

    item = json.loads(desc)
    many = json.dumps({"stores": [item] * 90}).encode()
    assert len(many) > 65536
    double = Double({("GET", "/v1/stores"): answer(body=many)})
    assert len(connect(double.url, timeout=5).stores()) == 90
    double.shutdown()


def test_store_lists_and_aggregates_are_checked_by_the_schema(truth):
    """The answers' models of hevr.remote.schema are the client's definition too: a store list or a
    verification answer that breaks them is a RemoteAnswerError naming the field (no hand parsing)."""
    from hevr.remote.render import _aggregate
    from hevr.remote.volume import parse_stores

    ev, _, _, _, desc, _ = truth
    item, url = json.loads(desc), "http://s"
    assert [(sid, name) for sid, name, _ in parse_stores({"stores": [item, dict(item, name="ct")]}, url)] == [
        (ev.meta.store_id, None),
        (ev.meta.store_id, "ct"),
    ]
    for doc, match in (
        ({"stores": "x"}, r"stores: expected an array"),
        ({}, r"missing \['stores'\]"),
        ({"stores": [], "more": 1}, r"extra fields \['more'\]"),
        ({"stores": [dict(item, id="x")]}, r"stores\[0\]\.id: expected 16 lower-case hex"),
    ):
        with pytest.raises(hevr.RemoteAnswerError, match=match):
            parse_stores(doc, url)
    n = 1000003 * 1000033
    assert _aggregate(b'{"aggregate": "12345"}', n, url) == 12345
    for raw, match in (
        (b'{"aggregate": "5", "seed": "00"}', r"extra fields \['seed'\]"),
        (b'{"aggregate": 5}', "aggregate: expected a string"),
        (b"{}", r"missing \['aggregate'\]"),
        (b'{"aggregate": "5\\n"}', "aggregate: expected"),
        (b'{"aggregate": "0"}', r"in \(0, n²\)"),
    ):
        with pytest.raises(hevr.RemoteAnswerError, match=match):
            _aggregate(raw, n, url)
