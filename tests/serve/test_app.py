"""``hevr serve``'s application answers malformed, oversized and strange requests with clear 4xx
problem documents. These need no cluster: the app runs in process (Starlette's test client,
issue 48); what needs real sockets and a cluster is in test_app_live.py."""

from __future__ import annotations

import json
import types

import pytest
from starlette.testclient import TestClient

import hevr
from hevr.serve.app import create_app
from hevr.serve.run import open_stores


@pytest.fixture(scope="module")
def served(served_store):
    """The store as ``hevr serve`` opens it (by its name ``v``), no cluster, no tokens."""
    s = served_store
    return types.SimpleNamespace(ev=s.ev, app=create_app(open_stores([str(s.dir / "v.zarr")])))


@pytest.fixture(scope="module")
def http(served):
    with TestClient(served.app) as c:
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


@pytest.mark.parametrize(
    "body, status, words",
    [
        (b"{not json", 400, ["JSON"]),
        (b'{"view": {}, "channel": "scalar", "channel": "vector"}', 400, ["duplicate"]),
        (b"[1, 2]", 400, ["object"]),
        (
            b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "scalar", "colour": "red"}',
            400,
            ["extra fields", "colour"],
        ),
        (
            b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "scalar", "step": 1e999}',
            400,
            ["step"],
        ),
        (
            b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "scalar", "tile": '
            + b"9" * 60
            + b"}",
            400,
            ["JSON"],
        ),
        (
            b'{"view": {"position": [0,0,40], "focal_point": [0,0,0], "width": 100000}, "channel": "scalar"}',
            400,
            ["width"],
        ),
        (b'{"view": {"position": [0,0,40], "focal_point": [0,0,0]}, "channel": "secret"}', 400, ["channel"]),
        (b'{"view": {"position": [0,0,NaN], "focal_point": [0,0,0]}, "channel": "scalar"}', 400, ["JSON"]),
        (b"[" * 5000 + b"]" * 5000, 400, []),
        ('{"view": "\u00e9"}'.encode("latin-1"), 400, ["JSON"]),
    ],
)
def test_malformed_requests_are_clear_400s(served, http, body, status, words):
    r = http.post(
        f"/v1/stores/{served.ev.meta.store_id}/render", content=body, headers={"Content-Type": "application/json"}
    )
    _problem(r, status, *words)


def test_size_type_and_store_limits(served, http):
    sid = served.ev.meta.store_id
    _problem(
        http.post(f"/v1/stores/{sid}/render", content=b" " * (65 * 1024), headers={"Content-Type": "application/json"}),
        413,
        "65536",
    )

    def chunks():  # no Content-Length: counted as it comes
        for _ in range(100):
            yield b" " * 1024

    _problem(http.post(f"/v1/stores/{sid}/render", content=chunks(), headers={"Content-Type": "application/json"}), 413)
    body = json.dumps({"view": _cam(served), "channel": "scalar"})
    _problem(http.post(f"/v1/stores/{sid}/render", content=body, headers={"Content-Type": "text/plain"}), 415)
    _problem(http.post("/v1/stores/0123456789abcdef/render", json={"view": _cam(served), "channel": "scalar"}), 404)
    # a render too big for the planner's limits is a 422 naming the knob, before any work
    big = hevr.Camera.orbit(served.ev, width=4096, height=4096).to_dict()
    r = http.post(f"/v1/stores/{sid}/render", json={"view": big, "channel": "scalar", "step": 0.001})
    assert r.status_code in (400, 422), r.text
    # the store has no gradient channel
    _problem(http.post(f"/v1/stores/{sid}/render", json={"view": _cam(served), "channel": "gradient"}), 400, "gradient")
