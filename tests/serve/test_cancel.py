"""A render of ``hevr serve`` whose client leaves is cancelled on the cluster, and the server's
shutdown cancels the renders still running (issue 48, item 2). In process: the app is called as
ASGI with a client that goes away (``http.disconnect``), or through Starlette's test client; the
work is a slow task list on Dask's threaded scheduler, or the real render pipeline on an in-process
``distributed`` cluster with slowed map tasks. No speed asserts: the bounds are generous."""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time

import dask
import pytest
from distributed import Client, LocalCluster
from starlette.testclient import TestClient

import hevr
from hevr.runtime.scheduler import compute
from hevr.serve import jobs
from hevr.serve.app import create_app
from hevr.serve.run import open_stores

N_TASKS = 1000  # 0.05 s each on 2 threads: 25 s if nothing cancels them


@pytest.fixture
def quick_poll(monkeypatch):
    monkeypatch.setattr(jobs, "POLL_S", 0.05)


def _slow_render(started: list, done: threading.Event):
    """A render_image whose work is N_TASKS slow tasks on Dask's threaded scheduler."""

    def task(i):
        started.append(i)
        time.sleep(0.05)
        return i

    def render_image(ev, req, *, client, backend=None, stream=None):
        try:
            with dask.config.set(scheduler="threads", num_workers=2):
                compute(
                    [dask.delayed(task)(i, dask_key_name=f"slow-{i}") for i in range(N_TASKS)],
                    client=None,
                    progress=False,
                )
            raise AssertionError("the render ran to its end")
        finally:
            done.set()

    return render_image


async def _leave(app, path: str, body: dict, leave: threading.Event | None, slow_send: bool = False) -> list:
    """Call ``app`` as a client that goes away once its request is sent, when ``leave`` is set
    (None: never); the messages it was sent (``slow_send``: each send yields to the loop first, as a
    server's write may)."""
    raw = json.dumps(body).encode()
    sent: list = []
    gone = asyncio.Event()
    first = True

    async def receive():
        nonlocal first
        if first:
            first = False
            return {"type": "http.request", "body": raw, "more_body": False}
        await gone.wait()
        return {"type": "http.disconnect"}

    async def send(message):
        if slow_send:
            await asyncio.sleep(0.05)
        sent.append(message)

    async def trigger():
        while leave is None or not leave.is_set():
            await asyncio.sleep(0.02)
        gone.set()

    scope = {
        "type": "http",
        "asgi": {"version": "3.0", "spec_version": "2.3"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "query_string": b"",
        "root_path": "",
        "client": ("127.0.0.1", 40000),
        "server": ("127.0.0.1", 8750),
        "headers": [
            (b"host", b"127.0.0.1"),
            (b"content-type", b"application/json"),
            (b"content-length", str(len(raw)).encode()),
        ],
    }
    leaver = asyncio.ensure_future(trigger())
    await asyncio.wait_for(app(scope, receive, send), 120)
    leaver.cancel()
    return sent


def _body(ev):
    return {"view": hevr.Camera.orbit(ev, azimuth=5, width=16, height=16).to_dict(), "channel": "scalar"}


@pytest.mark.parametrize("endpoint", ["render", "stream"])
def test_a_client_that_leaves_cancels_its_render(served_store, monkeypatch, caplog, quick_poll, endpoint):
    started: list = []
    done = threading.Event()
    monkeypatch.setattr("hevr.serve.routes.render.render_image", _slow_render(started, done))
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]))
    working = threading.Event()
    threading.Thread(
        target=lambda: (time.sleep(0.01), [time.sleep(0.02) for _ in iter(lambda: bool(started), True)], working.set()),
        daemon=True,
    ).start()
    with caplog.at_level(logging.INFO, logger="hevr.serve"):
        asyncio.run(_leave(app, f"/v1/stores/v/{endpoint}", _body(served_store.ev), working))
        assert done.wait(60), "the render was not cancelled"
    count = len(started)
    assert 0 < count < N_TASKS
    time.sleep(0.5)
    assert len(started) == count  # no task starts after the cancellation
    limits = app.state.service.limits
    for _ in range(100):
        if limits.total == 0:
            break
        time.sleep(0.05)
    assert limits.total == 0 and limits.total_products == 0  # the slot is free
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "client left; render cancelled" in text and "internal error" not in text, text
    assert f"/v1/stores/v/{endpoint} 499" in text, text


def test_the_servers_shutdown_cancels_running_renders(served_store, monkeypatch, quick_poll):
    """The app's lifespan (what uvicorn runs at Ctrl-C): its shutdown cancels the running render,
    whose client gets a 503, and ends once the render's thread has."""
    started: list = []
    done = threading.Event()
    monkeypatch.setattr("hevr.serve.routes.render.render_image", _slow_render(started, done))
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]))

    async def main():
        events: asyncio.Queue = asyncio.Queue()
        said: list = []

        async def send(message):
            said.append(message["type"])

        await events.put({"type": "lifespan.startup"})
        life = asyncio.ensure_future(
            app({"type": "lifespan", "asgi": {"version": "3.0"}, "state": {}}, events.get, send)
        )
        call = asyncio.ensure_future(_leave(app, "/v1/stores/v/render", _body(served_store.ev), None))
        for _ in range(1200):
            if started:
                break
            await asyncio.sleep(0.05)
        assert started
        t0 = time.perf_counter()
        await events.put({"type": "lifespan.shutdown"})
        await asyncio.wait_for(life, 60)
        return await call, said, time.perf_counter() - t0

    sent, said, took = asyncio.run(main())
    assert said == ["lifespan.startup.complete", "lifespan.shutdown.complete"] and took < 60
    assert done.is_set() and len(started) < N_TASKS
    assert sent[0]["status"] == 503 and b"cancelled" in sent[1]["body"], sent
    limits = app.state.service.limits
    assert limits.total == 0 and limits.closed


def test_a_render_on_a_cluster_is_cancelled_there(served_store, monkeypatch, caplog, quick_poll):
    """The real pipeline on an in-process ``distributed`` cluster, each map task slowed: the client
    leaves, the render's futures are cancelled on the cluster (no task left processing), the slot is
    freed and the next render is served."""
    from hevr.rendering.pipeline import maps

    ran: list = []
    real = maps.brick_ray_products_multi

    def slow(*a, **k):
        ran.append(1)
        time.sleep(1.0)  # 27 map tasks on 2 threads: 13 s if nothing cancels them
        return real(*a, **k)

    monkeypatch.setattr(maps, "brick_ray_products_multi", slow)
    with (
        LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        app = create_app(open_stores([str(served_store.dir / "v.zarr")]), client=client)
        body = {
            "view": hevr.Camera.orbit(served_store.ev, azimuth=5, width=32, height=32).to_dict(),
            "channel": "vector",
            "sampling": "trilinear",
            "tile": 8,
        }
        working = threading.Event()

        def watch():
            while not ran:
                time.sleep(0.02)
            working.set()

        threading.Thread(target=watch, daemon=True).start()
        with caplog.at_level(logging.INFO, logger="hevr.serve"):
            asyncio.run(_leave(app, "/v1/stores/v/render", body, working))
        limits = app.state.service.limits
        for _ in range(600):
            if limits.total == 0 and not any(client.processing().values()):
                break
            time.sleep(0.1)
        assert limits.total == 0 and not any(client.processing().values())
        total = len(ran)
        time.sleep(1.0)
        assert len(ran) == total < 27  # nothing more runs for it: not all of the 27 bricks' map tasks ran
        assert "client left; render cancelled" in caplog.text
        monkeypatch.setattr(maps, "brick_ray_products_multi", real)
        small = {
            "view": hevr.Camera.orbit(served_store.ev, azimuth=5, width=8, height=8).to_dict(),
            "channel": "scalar",
        }
        with TestClient(app) as http:
            assert http.post("/v1/stores/v/render", json=small).status_code == 200


def _freed(limits, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while limits.total and time.monotonic() < deadline:
        time.sleep(0.05)
    return limits.total == 0 and limits.total_products == 0


@pytest.mark.parametrize("endpoint", ["stream", "render"])
def test_a_client_that_closes_right_after_its_request_cancels_its_render(served_store, monkeypatch, caplog, endpoint):
    """M5: the client is gone before the answer starts (Starlette then cancels a stream's response
    before its frames' generator runs): the render is cancelled all the same, its slot freed within
    seconds (uncancelled, its 1000 tasks take 25 s)."""
    monkeypatch.setattr(jobs, "POLL_S", 60.0)  # not the watcher: the answer's own end cancels a stream
    if endpoint == "render":
        monkeypatch.setattr(jobs, "POLL_S", 0.05)
    started: list = []
    done = threading.Event()
    monkeypatch.setattr("hevr.serve.routes.render.render_image", _slow_render(started, done))
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]))
    gone = threading.Event()
    gone.set()
    with caplog.at_level(logging.INFO, logger="hevr.serve"):
        asyncio.run(_leave(app, f"/v1/stores/v/{endpoint}", _body(served_store.ev), gone, slow_send=True))
        assert _freed(app.state.service.limits, 15), f"the render was not cancelled ({len(started)} tasks ran)"
    assert len(started) < N_TASKS // 2
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "client left; render cancelled" in text and f"/v1/stores/v/{endpoint} 499" in text, text


def test_a_job_cancelled_while_waiting_for_a_thread_frees_its_slot(served_store):
    """L1: the server cancels a request whose render waits for a thread of anyio's pool (all busy):
    its slot is freed at once, and its work never runs."""
    import anyio

    from hevr.runtime.cancel import Cancelled
    from hevr.serve.budget import Limits

    class Present:
        async def is_disconnected(self):
            return False

    limits, ran = Limits(2), []

    async def main():
        anyio.to_thread.current_default_thread_limiter().total_tokens = 1
        busy = threading.Event()
        blocker = asyncio.ensure_future(anyio.to_thread.run_sync(busy.wait, 60))
        await asyncio.sleep(0.1)
        job = asyncio.ensure_future(jobs.run_job(Present(), limits, limits.enter("a", 2), lambda: ran.append(1)))
        await asyncio.sleep(0.2)
        assert limits.total == 1
        job.cancel()
        with pytest.raises(Cancelled):
            await job
        freed = limits.total
        busy.set()
        await blocker
        await asyncio.sleep(0.2)
        return freed

    assert asyncio.run(main()) == 0 and limits.total == 0 and not ran


def test_shutdown_is_not_stalled_by_a_full_thread_pool(served_store, monkeypatch, quick_poll):
    """L2: renders hold every thread of anyio's pool (here its one): the lifespan's shutdown cancels
    them and waits on a thread of its own, so it ends (on the pool, it would wait forever)."""
    import anyio

    started: list = []
    done = threading.Event()
    monkeypatch.setattr("hevr.serve.routes.render.render_image", _slow_render(started, done))
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]))

    async def main():
        anyio.to_thread.current_default_thread_limiter().total_tokens = 1
        events: asyncio.Queue = asyncio.Queue()
        said: list = []

        async def send(message):
            said.append(message["type"])

        await events.put({"type": "lifespan.startup"})
        life = asyncio.ensure_future(
            app({"type": "lifespan", "asgi": {"version": "3.0"}, "state": {}}, events.get, send)
        )
        call = asyncio.ensure_future(_leave(app, "/v1/stores/v/render", _body(served_store.ev), None))
        for _ in range(1200):
            if started:
                break
            await asyncio.sleep(0.05)
        assert started
        await events.put({"type": "lifespan.shutdown"})
        await asyncio.wait_for(life, 30)
        return await call, said

    sent, said = asyncio.run(main())
    assert said == ["lifespan.startup.complete", "lifespan.shutdown.complete"]
    assert done.is_set() and len(started) < N_TASKS and sent[0]["status"] == 503
