"""``hevr serve`` survives its clients: malformed, oversized and strange requests get clear 4xx
problem documents, 100 concurrent requests are bounded, a client leaving mid-stream frees its
slot, and the server goes on serving."""

from __future__ import annotations

import json
import socket
import threading
from concurrent.futures import ThreadPoolExecutor
from urllib.parse import urlsplit

import httpx
import pytest

import hevr
from hevr.remote.protocol import END, UNITS_MEDIA, unpack_head


@pytest.fixture(scope="module")
def http(served):
    with httpx.Client(base_url=served.url, timeout=120) as c:
        yield c


def _cam(served, w=8, h=8):
    return hevr.Camera.orbit(served.ev, azimuth=5, width=w, height=h).to_dict()


def _problem(r, status, *words):
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    doc = r.json()
    assert doc["status"] == status and isinstance(doc["detail"], str)
    for w in words:
        assert w in doc["detail"], doc["detail"]
    return doc


def test_version_openapi_and_stores(served, http):
    assert http.get("/v1").json()["api"] == 1
    doc = http.get("/v1/openapi.json").json()
    assert doc["openapi"].startswith("3.1") and "/v1/stores/{store}/render" in doc["paths"]
    assert doc["components"]["schemas"]["RenderRequest"]["additionalProperties"] is False
    assert doc["components"]["schemas"]["Store"]["required"] == ["id", "name", "metadata"]
    (item,) = http.get("/v1/stores").json()["stores"]
    assert item["id"] == served.ev.meta.store_id and item["metadata"] == served.ev.meta.to_dict()
    assert item["name"] == "v" and http.get("/v1/stores/v").json() == item  # by its name (issue 47) and its id
    assert http.get(f"/v1/stores/{served.ev.meta.store_id}").json() == item
    _problem(http.get("/v2/anything"), 404, "/v1")
    _problem(http.get(f"/v1/stores/{served.ev.meta.store_id}/render"), 405)


@pytest.mark.parametrize("body, status, words", [
    (b"{not json", 400, ["JSON"]),
    (b'{"view": {}, "channel": "scalar", "channel": "vector"}', 400, ["duplicate"]),
    (b'[1, 2]', 400, ["object"]),
    (b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "scalar", "colour": "red"}', 400,
     ["extra fields", "colour"]),
    (b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "scalar", "step": 1e999}', 400, ["step"]),
    (b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "scalar", "tile": '
     + b"9" * 60 + b"}", 400, ["JSON"]),
    (b'{"view": {"position": [0,0,40], "focal_point": [0,0,0], "width": 100000}, "channel": "scalar"}', 400,
     ["width"]),
    (b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "secret"}', 400, ["channel"]),
    (b'{"view": {"position": [0,0,NaN], "focal_point": [0,0,0]}, "channel": "scalar"}', 400, ["JSON"]),
    (b"[" * 5000 + b"]" * 5000, 400, []),
    ("{\"view\": \"\u00e9\"}".encode("latin-1"), 400, ["JSON"]),
])
def test_malformed_requests_are_clear_400s(served, http, body, status, words):
    r = http.post(f"/v1/stores/{served.ev.meta.store_id}/render", content=body,
                  headers={"Content-Type": "application/json"})
    _problem(r, status, *words)


def test_size_type_and_store_limits(served, http):
    sid = served.ev.meta.store_id
    _problem(http.post(f"/v1/stores/{sid}/render", content=b" " * (65 * 1024),
                       headers={"Content-Type": "application/json"}), 413, "65536")

    def chunks():  # no Content-Length: counted as it comes
        for _ in range(100):
            yield b" " * 1024
    _problem(http.post(f"/v1/stores/{sid}/render", content=chunks(), headers={"Content-Type": "application/json"}),
             413)
    body = json.dumps({"view": _cam(served), "channel": "scalar"})
    _problem(http.post(f"/v1/stores/{sid}/render", content=body, headers={"Content-Type": "text/plain"}), 415)
    _problem(http.post("/v1/stores/0123456789abcdef/render", json={"view": _cam(served), "channel": "scalar"}), 404)
    # a render too big for the planner's limits is a 422 naming the knob, before any work
    big = hevr.Camera.orbit(served.ev, width=4096, height=4096).to_dict()
    r = http.post(f"/v1/stores/{sid}/render", json={"view": big, "channel": "scalar", "step": 0.001})
    assert r.status_code in (400, 422), r.text
    # the store has no gradient channel
    _problem(http.post(f"/v1/stores/{sid}/render", json={"view": _cam(served), "channel": "gradient"}), 400,
             "gradient")


def test_hundred_concurrent_requests_are_bounded(served, http):
    sid = served.ev.meta.store_id

    def one(i):
        cam = hevr.Camera.orbit(served.ev, azimuth=200 + i, width=6, height=6).to_dict()
        with httpx.Client(base_url=served.url, timeout=180) as c:
            r = c.post(f"/v1/stores/{sid}/render", json={"view": cam, "channel": "scalar"})
            return r.status_code, r.headers.get("retry-after")

    with ThreadPoolExecutor(100) as pool:
        results = list(pool.map(one, range(100)))
    codes = [c for c, _ in results]
    assert set(codes) <= {200, 429}, codes
    assert codes.count(200) >= 1 and codes.count(429) >= 1  # at most 4 at once: the rest told to retry
    assert all(ra == "1" for c, ra in results if c == 429)
    assert http.get("/v1").status_code == 200
    assert served.proc.poll() is None


def test_a_client_leaving_mid_stream_frees_its_slot(served, http):
    sid = served.ev.meta.store_id
    parts = urlsplit(served.url)
    body = json.dumps({"view": hevr.Camera.orbit(served.ev, azimuth=77, width=20, height=20).to_dict(),
                       "channel": "vector", "sampling": "trilinear"}).encode()
    for _ in range(6):  # more than the server's 4 slots: each must be freed when its client leaves
        s = socket.create_connection((parts.hostname, parts.port), timeout=30)
        s.sendall(b"POST /v1/stores/%s/stream HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                  b"Content-Length: %d\r\n\r\n" % (sid.encode(), len(body)) + body)
        s.recv(64)
        s.close()
    ok = threading.Event()

    def stream():
        with httpx.Client(base_url=served.url, timeout=120) as c:
            with c.stream("POST", f"/v1/stores/{sid}/stream", json={"view": _cam(served), "channel": "scalar"}) as r:
                assert r.status_code == 200 and r.headers["content-type"] == UNITS_MEDIA
                data = r.read()
        index = None
        while data:
            index, n = unpack_head(data[:8])
            data = data[8 + n:]
        assert index == END
        ok.set()

    for _ in range(60):  # the abandoned renders finish and free their slots
        try:
            stream()
            break
        except AssertionError:
            import time
            time.sleep(0.5)
    assert ok.is_set()
    assert served.proc.poll() is None


def test_log_holds_requests_without_tokens_or_keys(served):
    text = "\n".join(served.lines)
    assert "Authorization" not in text and "Bearer" not in text
