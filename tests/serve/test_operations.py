"""Operating ``hevr serve`` (issue 48, item 7), in process (Starlette's test client): the health
endpoint, the request log's format (a client that left included), tokens re-read without a
restart, and a store re-encrypted under the running server opened again (off the event loop:
a 503 meanwhile)."""

from __future__ import annotations

import json
import logging
import os
import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import dask
import httpx
import numpy as np
import pytest
from _serving import hevr_serve, wait_until
from starlette.testclient import TestClient

import hevr
from hevr.serve.app import create_app
from hevr.serve.token_file import TokenFile
from hevr.serve.tokens import TokenTable, hash_token, new_token

LINE = re.compile(r"^(\S+) (GET|HEAD|POST) (\S+) (\d{3}) (\d+) (\S+) (\d+\.\d{3})( client left)?$")


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256):
    pub, _ = keypair256
    d = tmp_path_factory.mktemp("ops")
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(hevr.phantom(8), str(d / "ct.zarr"), pub, brick=4, progress=False)
    return d, ev


def _tokens(path, **names):
    path.write_text(
        json.dumps(
            {"version": 1, "tokens": [{"name": n, "sha256": hash_token(t), "stores": ["*"]} for n, t in names.items()]}
        )
    )
    path.chmod(0o600)


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.mark.parametrize("tokens", [False, True])
def test_health_needs_no_token_and_names_no_store(store, tmp_path, tokens, caplog):
    d, ev = store
    table = None
    if tokens:
        _tokens(tmp_path / "t.json", alice=new_token())
        table = TokenTable.load(tmp_path / "t.json")
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr")}, tokens=table)
    with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"):
        r = http.get("/v1/health")
        assert r.status_code == 200 and r.json() == {"status": "ok"}
        assert ev.meta.store_id not in r.text and "ct" not in r.text
        assert r.headers["cache-control"] == "no-store"
        assert http.head("/v1/health").status_code == 200
        assert http.get("/v1/stores").status_code == (401 if tokens else 200)
        assert http.post("/v1/health").status_code == 405
    lines = [rec.getMessage() for rec in caplog.records if rec.name == "hevr.serve"]
    assert any(re.fullmatch(r"testclient GET /v1/health 200 \d+ - \d+\.\d{3}", x) for x in lines), lines
    assert any(x.startswith("testclient HEAD /v1/health 200 0 - ") for x in lines), lines


def test_the_request_log_line(store, tmp_path, caplog):
    d, ev = store
    alice = new_token()
    _tokens(tmp_path / "t.json", alice=alice)
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr")}, tokens=TokenTable.load(tmp_path / "t.json"))
    with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"):
        r = http.get("/v1/stores?secret=xyz", headers={"Authorization": f"Bearer {alice}"})
        http.get("/v1/stores/a%0Ab")  # a newline in the path stays escaped: one line
        http.get("/v1/stores", headers={"Authorization": "Bearer nope"})
    lines = [rec.getMessage() for rec in caplog.records if rec.name == "hevr.serve"]
    assert len(lines) == 3 and all(LINE.match(x) for x in lines), lines
    m = LINE.match(lines[0])
    assert m.group(3) == "/v1/stores" and m.group(4) == "200" and int(m.group(5)) == len(r.content)
    assert m.group(6) == "alice"
    assert LINE.match(lines[1]).group(3) == "/v1/stores/a%0Ab" and LINE.match(lines[1]).group(4) == "401"
    assert LINE.match(lines[2]).group(6) == "-"
    text = "\n".join(lines)
    assert alice not in text and "nope" not in text and "secret" not in text and hash_token(alice) not in text


def _stream_line(chunks, caplog, leave: bool) -> str:
    """The log line of a stream of ``chunks()`` whose client leaves after 0.2 s (``leave``) or stays."""
    import anyio
    from starlette.requests import Request
    from starlette.responses import StreamingResponse

    from hevr.serve.routes.base import endpoint

    async def fn(request, caller):
        return StreamingResponse(chunks())

    scope = {
        "type": "http",
        "method": "POST",
        "path": "/v1/stores/x/stream",
        "raw_path": b"/v1/stores/x/stream",
        "query_string": b"",
        "headers": [],
        "client": ("10.0.0.7", 5000),
        "asgi": {"spec_version": "2.3"},
    }
    messages = [{"type": "http.request", "body": b"", "more_body": False}, {"type": "http.disconnect"}]

    async def receive():
        if len(messages) == 1:
            await anyio.sleep(0.2 if leave else 60)
        return messages.pop(0)

    async def send(message):
        pass

    async def run():
        response = await endpoint(fn, public=True)(Request(scope, receive, send))
        await response(scope, receive, send)

    with caplog.at_level(logging.INFO, logger="hevr.serve"):
        try:
            anyio.run(run)
        except RuntimeError:
            pass
    (line,) = [rec.getMessage() for rec in caplog.records if rec.name == "hevr.serve"]
    return line


def test_a_stream_whose_client_left_is_logged_as_such(caplog):
    import anyio

    async def chunks():
        yield b"abcd"
        await anyio.sleep(30)
        yield b"never"

    line = _stream_line(chunks, caplog, leave=True)
    assert re.fullmatch(r"10\.0\.0\.7 POST /v1/stores/x/stream 499 4 - \d+\.\d{3} client left", line), line


def test_a_stream_the_server_broke_off_is_logged_as_failed(caplog):
    async def chunks():
        yield b"abcdef"
        raise RuntimeError("a bug")

    line = _stream_line(chunks, caplog, leave=False)
    assert re.fullmatch(r"10\.0\.0\.7 POST /v1/stores/x/stream 500 6 - \d+\.\d{3} failed", line), line


def test_tokens_are_read_again_when_the_file_changes(store, tmp_path, caplog):
    d, _ = store
    path = tmp_path / "t.json"
    alice, bob = new_token(), new_token()
    _tokens(path, alice=alice)
    clock = Clock()
    tf = TokenFile(path, clock=clock)
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr")}, tokens=tf)

    def status(token):
        return http.get("/v1/stores", headers={"Authorization": f"Bearer {token}"}).status_code

    with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"):
        assert (status(alice), status(bob)) == (200, 401)
        _tokens(path, bob=bob)  # alice revoked, bob added
        assert status(alice) == 200  # looked at no more than once a second
        clock.t += 1.5
        assert (status(alice), status(bob)) == (401, 200)
        assert any("added: bob; removed: alice" in r.getMessage() for r in caplog.records)
        path.write_text("{not json")  # a bad file keeps the tokens in force, and says so once
        clock.t += 1.5
        assert status(bob) == 200
        clock.t += 1.5
        assert status(bob) == 200 and status(alice) == 401
        errors = [r for r in caplog.records if r.levelno == logging.ERROR]
        assert len(errors) == 1 and "stay in force" in errors[0].getMessage(), errors
        os.unlink(path)  # so does a file gone
        clock.t += 1.5
        assert status(bob) == 200
        _tokens(path, alice=alice)
        tf.reread()  # SIGHUP: at once, whatever the clock
        assert (status(alice), status(bob)) == (200, 401)


def _watched_by(app, clock):
    for w in app.state.service.watch._files.values():
        w.clock, w.checked = clock, 0.0


def _ready(http, url, body=None):
    """The answer to ``url`` once the store is no longer being reopened (503s until then)."""
    answers = []

    def done():
        answers.append(http.post(url, json=body) if body is not None else http.get(url))
        return answers[-1].status_code != 503

    assert wait_until(done, timeout=60), answers[-1].text
    return answers[-1]


def test_a_store_re_encrypted_under_the_server_is_opened_again(store, tmp_path, keypair256, caplog):
    _, priv = keypair256
    path = tmp_path / "ct.zarr"
    vol = hevr.phantom(8)
    with dask.config.set(scheduler="sync"):
        old = hevr.encrypt_volume(vol, str(path), priv.public_key, brick=4, progress=False)
    app = create_app({"ct": hevr.open_volume(path)})
    clock = Clock()
    _watched_by(app, clock)
    cam = hevr.Camera.orbit(old, azimuth=5, width=6, height=5)
    body = {"view": cam.to_dict(), "channel": "scalar"}
    with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"):
        before = http.post("/v1/stores/ct/render", json=body)
        assert before.status_code == 200
        with dask.config.set(scheduler="sync"):
            new = hevr.encrypt_volume(
                np.flip(vol, 0).copy(), str(path), priv.public_key, brick=4, overwrite=True, progress=False
            )
        assert new.meta.store_id != old.meta.store_id
        other = {"view": hevr.Camera.orbit(old, azimuth=50, width=6, height=5).to_dict(), "channel": "scalar"}
        within = http.post("/v1/stores/ct/render", json=other)  # within the second: the old handle's digests
        assert within.status_code == 500 and "digest mismatch" in within.text, within.text  # (the 500)
        r = _ready(http, "/v1/stores/ct/render", body)  # the failed check had the store looked at: opened again
        assert r.status_code == 200, r.text
        with TestClient(create_app({"ct": hevr.open_volume(path)})) as fresh:  # as a restarted server answers
            assert r.content == fresh.post("/v1/stores/ct/render", json=body).content != before.content
        (item,) = http.get("/v1/stores").json()["stores"]
        assert (item["id"], item["name"]) == (new.meta.store_id, "ct")
        assert http.post(f"/v1/stores/{old.meta.store_id}/render", json=body).status_code == 404
        assert http.post(f"/v1/stores/{new.meta.store_id}/render", json=body).status_code == 200
    assert any("re-encrypted" in r.getMessage() and new.meta.store_id in r.getMessage() for r in caplog.records)


def test_a_slow_reopen_blocks_neither_the_server_nor_a_second_reopen(store, tmp_path, monkeypatch, caplog):
    """Opening a changed store again (``--persist``: minutes) runs off the event loop: /v1/health
    answers meanwhile, the store is a 503 with Retry-After, and one reopen runs at a time."""
    from hevr.serve import store_watch

    d, ev = store
    gate, entered, calls = threading.Event(), threading.Event(), []
    real = store_watch.open_volume

    def slow_open(path, *args, **kwargs):
        calls.append(path)
        entered.set()
        gate.wait(60)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(store_watch, "open_volume", slow_open)
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr")})
    clock = Clock()
    _watched_by(app, clock)
    meta = d / "ct.zarr" / "zarr.json"
    st = meta.stat()
    with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"), ThreadPoolExecutor(2) as pool:
        try:
            os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # changed on disk (the same store)
            clock.t += 1.5
            first = pool.submit(http.get, "/v1/stores/ct")
            assert entered.wait(30)
            t0 = time.monotonic()
            health = pool.submit(http.get, "/v1/health").result(timeout=20)  # the loop is not blocked
            assert health.status_code == 200 and time.monotonic() - t0 < 20
            r = first.result(timeout=20)
            assert r.status_code == 503 and r.headers["retry-after"] == "2", r.text
            assert "being opened again" in r.json()["detail"] and str(d) not in r.text
            clock.t += 1.5
            assert http.get("/v1/stores/ct").status_code == 503 and len(calls) == 1  # one reopen at a time
            assert http.get("/v1/stores/nope").status_code == 404
        finally:
            gate.set()
        assert _ready(http, "/v1/stores/ct").json()["id"] == ev.meta.store_id
        assert len(calls) == 1
    os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert any("changed on disk: opened again" in r.getMessage() for r in caplog.records)


def test_a_store_that_cannot_be_opened_again_yet_keeps_its_handle(store, monkeypatch, caplog):
    from hevr.serve import store_watch

    d, ev = store
    real, calls = store_watch.open_volume, []

    def failing_once(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 1:
            raise hevr.ParameterError("zarr.json: expected a whole document, got half of one")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(store_watch, "open_volume", failing_once)
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr")})
    clock = Clock()
    _watched_by(app, clock)
    meta = d / "ct.zarr" / "zarr.json"
    st = meta.stat()
    try:
        with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"):
            for shift in (1, 2):  # still being written; then whole
                os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns + shift * 10**9))
                clock.t += 1.5
                assert _ready(http, "/v1/stores/ct").json()["id"] == ev.meta.store_id
                clock.t += 1.5
                assert http.get("/v1/stores/ct").status_code == 200 and len(calls) == shift  # tried once per version
    finally:
        os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns))
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert sum("cannot be opened yet" in x for x in said) == 1 and any("opened again" in x for x in said), said


@pytest.mark.parametrize("quiet", [False, True])
def test_hevr_serve_logs_each_request_by_default(store, quiet):
    d, _ = store
    with hevr_serve(str(d / "ct.zarr"), *(["--no-request-log"] if quiet else [])) as (url, proc, lines):
        assert httpx.get(f"{url}/v1/health", timeout=30).json() == {"status": "ok"}
        httpx.get(f"{url}/v1/stores", timeout=30)
        seen = wait_until(lambda: any(" GET /v1/stores " in x for x in lines), timeout=2 if quiet else 30)
    stamp = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ INFO "
    logged = [x for x in lines if re.match(stamp, x)]
    if quiet:
        assert not seen and not logged, lines
    else:
        assert re.fullmatch(stamp + r"127\.0\.0\.1 GET /v1/health 200 15 - \d+\.\d{3}", logged[0]), lines
        assert re.fullmatch(stamp + r"127\.0\.0\.1 GET /v1/stores 200 \d+ anonymous \d+\.\d{3}", logged[1]), lines


def test_a_new_version_that_cannot_be_made_resident_is_a_503_and_tried_again(store, monkeypatch, caplog):
    """``--persist``: a changed store that opens but cannot be made resident (the workers' memory) is not
    served from its old resident copy (what the owner replaced) nor left to fail every render: 503 while
    it waits, tried again after RETRY_FIRST seconds, then served (the file does not change again)."""
    from hevr.serve import store_watch
    from hevr.store.reader import EncryptedVolume

    d, ev = store
    res = hevr.open_volume(d / "ct.zarr").persist()
    app = create_app({"ct": res})
    clock = Clock()
    _watched_by(app, clock)
    app.state.service.watch.clock = clock
    real, calls = EncryptedVolume.persist, []

    def fails_once(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise hevr.MemoryLimitError("persist: expected room on the workers, got none")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(EncryptedVolume, "persist", fails_once)
    meta = d / "ct.zarr" / "zarr.json"
    st = meta.stat()
    try:
        with TestClient(app) as http, caplog.at_level(logging.INFO, logger="hevr.serve"):
            os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
            clock.t += 1.5
            assert http.get("/v1/stores/ct").status_code == 503
            said = lambda: any("could not be made resident" in r.getMessage() for r in caplog.records)  # noqa: E731
            assert wait_until(lambda: http.get("/v1/stores/ct").status_code == 503 and said(), timeout=60)
            clock.t += 1.5
            assert http.get("/v1/stores/ct").status_code == 503 and len(calls) == 1  # waits: not the old copy
            clock.t += store_watch.RETRY_FIRST
            assert _ready(http, "/v1/stores/ct").json()["id"] == ev.meta.store_id
            assert len(calls) == 2
    finally:
        os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns))
