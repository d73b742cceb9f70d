"""A cost bound for every request of ``hevr serve`` (issue 48, item 2): the bombs of the issue — a
tiny ``step``, ``tile`` 1, 2048² and 4096² images — are refused from their public parameters before
any work, with a problem document naming the limit; the viewer's 512² frame of a 512×512×300 CT
passes the default budget; a token's products in flight are bounded. In process (Starlette's test
client); the render itself is replaced where only its admission is under test."""

from __future__ import annotations

import contextlib
import json
import threading
import time
import types

import dask
import numpy as np
import pytest
from starlette.testclient import TestClient

import hevr
from hevr.remote.protocol import RenderRequest
from hevr.rendering.planning.request import ray_cost
from hevr.serve import budget as budget_module
from hevr.serve import jobs
from hevr.serve.app import create_app
from hevr.serve.budget import Budget, Limits, parse_count
from hevr.serve.problems import Problem
from hevr.serve.run import open_stores

CT = (300, 512, 512)  # (nz, ny, nx)


def _ct(vector_dims=4):
    """A store's public face as the budget reads it: a 512×512×300 CT with 4 vector components."""
    meta = types.SimpleNamespace(packing=None, vector=types.SimpleNamespace(dims=vector_dims), gradient=None)
    return types.SimpleNamespace(meta=meta, shape=CT, spacing=(1.0, 1.0, 1.0), level=0)


@pytest.fixture(scope="module")
def app(served_store):
    return create_app(open_stores([str(served_store.dir / "v.zarr")]))


@pytest.fixture(scope="module")
def http(app):
    with TestClient(app) as c:
        yield c


@pytest.fixture
def no_render(monkeypatch):
    """Any render that starts fails the test: a refusal must come before any work."""

    def render_image(*a, **k):
        raise AssertionError("a refused request started a render")

    monkeypatch.setattr("hevr.serve.routes.render.render_image", render_image)
    monkeypatch.setattr("hevr.serve.routes.render.verify_aggregate", render_image)


def _body(ev, w, h, **kw):
    return {"view": hevr.Camera.orbit(ev, azimuth=5, width=w, height=h).to_dict(), "channel": "scalar", **kw}


@pytest.mark.parametrize(
    "w, h, kw, words",
    [
        (8, 8, {"step": 1e-6}, ["step: expected at least 0.25", "got 1e-06"]),
        (256, 256, {"tile": 1}, ["tile: expected at least 4 for a 256x256 image", "got 1"]),
        (2048, 2048, {}, ["width, height: expected an image of at most 1048576 pixels", "--max-pixels", "2048x2048"]),
        (4096, 4096, {}, ["--max-pixels", "4096x4096"]),
        (8, 8, {"step": 1e-6, "sampling": "trilinear"}, ["step"]),
    ],
)
@pytest.mark.parametrize("endpoint", ["render", "stream"])
def test_the_issues_bombs_are_refused_before_any_work(served_store, app, http, no_render, w, h, kw, words, endpoint):
    t0 = time.perf_counter()
    r = http.post(f"/v1/stores/v/{endpoint}", json=_body(served_store.ev, w, h, **kw))
    took = time.perf_counter() - t0
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json"), r.text
    doc = r.json()
    assert doc["title"] == "render over the server's budget"
    for word in words:
        assert word in doc["detail"], doc["detail"]
    assert took < 30, took  # milliseconds when idle; generous on a loaded machine
    assert app.state.service.limits.total == 0


def test_a_verify_request_has_the_same_budget(served_store, http, no_render):
    body = {"render": _body(served_store.ev, 2048, 2048), "seed": "00" * 32}
    r = http.post("/v1/stores/v/verify", json=body)
    assert r.status_code == 422 and "--max-pixels" in r.json()["detail"], r.text


def test_products_over_the_budget_name_the_limit_and_the_estimate(served_store, no_render):
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]), budget=Budget(max_products=10**5))
    with TestClient(app) as http:
        r = http.post(
            "/v1/stores/v/render", json=_body(served_store.ev, 64, 64, sampling="trilinear", channel="vector")
        )
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith(
        "products: expected at most 1e+05 for one render on this server (--max-products), got an estimated "
    ), detail
    assert "64x64 rays" in detail and "8 voxels a sample, 3 ciphertexts a voxel" in detail, detail


def test_the_viewers_512_frame_of_a_ct_passes_the_default_budget():
    b = Budget()
    for az, el in ((30, 20), (0, 0), (45, 35), (90, 0)):
        cam = hevr.Camera.orbit(CT, azimuth=az, elevation=el, width=512, height=512)
        req = RenderRequest(view=cam, channel="vector", sampling="trilinear")
        cost = b.check(_ct(), req)
        assert cost.products <= b.max_products and cost.rays == 512 * 512
    # every ray as long as the box's diagonal: the bound the default was sized for
    assert 512 * 512 * 785 * 8 * 4 <= b.max_products
    # four times the pixels, close up (the volume fills the frame): over it
    cam = hevr.Camera.orbit(CT, azimuth=30, elevation=20, width=1024, height=1024, distance=400)
    with pytest.raises(Problem) as err:
        b.check(_ct(), RenderRequest(view=cam, channel="vector", sampling="trilinear", tile=32))
    assert err.value.status == 422 and "--max-products" in err.value.detail


def test_the_estimate_is_the_formula():
    cam = hevr.Camera.orbit((16, 16, 16), azimuth=10, width=16, height=16)
    near = ray_cost(cam, (16, 16, 16), (1, 1, 1), 1.0, "nearest", 1)
    tri = ray_cost(cam, (16, 16, 16), (1, 1, 1), 1.0, "trilinear", 3)
    half = ray_cost(cam, (16, 16, 16), (1, 1, 1), 0.5, "nearest", 1)
    assert near.products == near.samples > 0 and tri.products == 24 * tri.samples == 24 * near.samples
    assert 1.8 * near.samples <= half.samples <= 2.2 * near.samples + 256
    packed = ray_cost(cam, (16, 16, 16), (1, 1, 1), 1.0, "trilinear", 1, packed=True)
    assert packed.products == 16 * 16 * 16 * 4


def test_a_tokens_products_in_flight_are_bounded(served_store, monkeypatch):
    """Two renders at once from one token: the second is over the token's products in flight (429,
    Retry-After); once the first ends, it is accepted."""
    body = _body(served_store.ev, 16, 16)
    one = Budget().check(served_store.ev, RenderRequest.from_dict(body)).products
    budget = Budget(max_products=one, max_token_products=one + one // 2)
    release, entered = threading.Event(), threading.Event()

    def render_image(ev, req, *, client, backend=None, stream=None):
        entered.set()
        assert release.wait(60)
        raise Problem(503, "held", "held: the test's render ends here")

    monkeypatch.setattr("hevr.serve.routes.render.render_image", render_image)
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]), budget=budget)
    with TestClient(app) as http:
        first: dict = {}
        t = threading.Thread(target=lambda: first.setdefault("r", http.post("/v1/stores/v/render", json=body)))
        t.start()
        assert entered.wait(60)
        r = http.post("/v1/stores/v/render", json=body)
        assert r.status_code == 429 and r.headers["retry-after"] == "5", r.text
        assert "products in flight: expected at most" in r.json()["detail"] and "--max-token-products" in r.text
        release.set()
        t.join(60)
        assert first["r"].status_code == 503 and app.state.service.limits.total == 0
        entered.clear()
        monkeypatch.setattr(jobs, "POLL_S", 0.05)
        t = threading.Thread(target=lambda: first.setdefault("s", http.post("/v1/stores/v/render", json=body)))
        t.start()
        assert entered.wait(60)  # the slot and the products were freed: accepted
        t.join(60)


def test_limits_count_products_per_token_and_in_all():
    lim = Limits(2, Budget(max_products=100, max_token_products=150))
    with lim.slot("a", 2, 100):
        with pytest.raises(Problem) as err:
            with lim.slot("a", 2, 60):
                pass
        assert err.value.status == 429 and "for this token" in err.value.detail
        with lim.slot("b", 2, 100):
            assert lim.total == 2 and lim.total_products == 200
    assert lim.total == lim.total_products == 0 and lim.products == {"a": 0, "b": 0}
    lim = Limits(4, Budget(max_products=100))
    with lim.slot("a", 4, 100), lim.slot("b", 4, 100), lim.slot("c", 4, 100), lim.slot("d", 4, 100):
        with pytest.raises(Problem) as err:
            with lim.slot("e", 4, 1):
                pass
    assert "--max-concurrent" in err.value.detail or "concurrent renders" in err.value.detail


def test_the_budget_comes_from_the_dask_config():
    with dask.config.set(
        {"hevr.serve.max-products": "1e6", "hevr.serve.max-pixels": 4096, "hevr.serve.max-token-products": 3 * 10**6}
    ):
        b = Budget.from_config()
    assert (b.max_products, b.max_pixels, b.token_products) == (10**6, 4096, 3 * 10**6)
    with dask.config.set({"hevr.serve.max-pixels": 2**40}), pytest.raises(hevr.ParameterError, match="max-pixels"):
        Budget.from_config()


def test_limits_close_cancels_the_running_and_refuses_until_opened():
    lim = Limits(2)
    jobs_seen: list = []

    def hold():
        with lim.slot("a", 2, 1) as job:
            jobs_seen.append(job)
            job.wait(60)

    t = threading.Thread(target=hold)
    t.start()
    for _ in range(600):
        if lim.total:
            break
        time.sleep(0.05)
    assert lim.close(timeout=60) and jobs_seen[0].cancelled and lim.total == 0
    t.join(60)
    with pytest.raises(Problem) as err:
        with lim.slot("a", 2, 1):
            pass
    assert err.value.status == 503
    lim.open()
    with lim.slot("a", 2, 1) as job:
        assert not job.cancelled


def test_a_level_costs_its_own_samples_and_a_packed_store_its_slices(served_store, keypair256, tmp_path):
    ev = served_store.ev
    cam = hevr.Camera.orbit(ev, azimuth=5, width=16, height=16)
    full = Budget().check(ev, RenderRequest(view=cam, channel="scalar", level=0))
    half = Budget().check(ev, RenderRequest(view=cam, channel="scalar", level=1))
    assert 0 < half.samples < full.samples  # step·2 through a level of half the voxels
    _, priv = keypair256
    vol = np.random.default_rng(3).integers(0, 256, (13, 9, 11)).astype(np.uint8)
    pk = hevr.encrypt_volume(
        vol, str(tmp_path / "p.zarr"), priv, brick=4, spacing=(1.0, 0.8, 1.3), layout="packed", progress=False
    )
    cam = hevr.Camera.orbit(pk, azimuth=60, elevation=10, width=14, height=11, parallel=True)
    for sampling, c in (("nearest", 1), ("trilinear", 4)):
        cost = Budget().check(pk, RenderRequest(view=cam, channel="scalar", sampling=sampling, tile=4))
        assert cost.products == 14 * 11 * 13 * c
    app = create_app({"p": hevr.open_volume(str(tmp_path / "p.zarr"))})
    with TestClient(app) as http:
        body = {"view": cam.to_dict(), "channel": "scalar", "sampling": "trilinear", "tile": 4}
        assert http.post("/v1/stores/p/render", json=body).status_code == 200
        r = http.post(
            "/v1/stores/p/render",
            json=dict(
                body, tile=1, view=hevr.Camera.orbit(pk, azimuth=60, width=128, height=128, parallel=True).to_dict()
            ),
        )
        assert r.status_code == 422 and r.json()["detail"].startswith("tile: expected at least 2"), r.text


def _holding(monkeypatch):
    """A render_image that holds its slot until released; (entered, release)."""
    release, entered = threading.Event(), threading.Event()

    def render_image(ev, req, *, client, backend=None, stream=None):
        entered.set()
        assert release.wait(60)
        raise Problem(503, "held", "held: the test's render ends here")

    monkeypatch.setattr("hevr.serve.routes.render.render_image", render_image)
    return entered, release


@contextlib.contextmanager
def _released(release: threading.Event):
    """Release the held render however the block ends (a failed assert does not hang the test)."""
    try:
        yield
    finally:
        release.set()


def _counting(monkeypatch) -> list:
    """Count the estimates (request_cost calls) the budget makes."""
    calls: list = []
    real = budget_module.request_cost

    def counted(*a, **k):
        calls.append(a[1])
        return real(*a, **k)

    monkeypatch.setattr(budget_module, "request_cost", counted)
    budget_module._COSTS.clear()  # no estimate kept from another test
    return calls


def test_a_token_at_its_limit_is_refused_before_any_estimate(served_store, monkeypatch):
    """M2: the concurrency count comes before the estimate (which casts every ray): a token at its
    ``concurrent`` limit gets its 429 for free; the same request again is not estimated twice."""
    entered, release = _holding(monkeypatch)
    calls = _counting(monkeypatch)
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]), max_concurrent=1)
    with TestClient(app) as http, _released(release):
        first: dict = {}
        body = _body(served_store.ev, 16, 16)
        t = threading.Thread(target=lambda: first.setdefault("r", http.post("/v1/stores/v/render", json=body)))
        t.start()
        assert entered.wait(60) and len(calls) == 1
        for w in (32, 48, 64):  # other views: each would be a fresh estimate
            r = http.post("/v1/stores/v/render", json=_body(served_store.ev, w, w))
            assert r.status_code == 429 and r.headers["retry-after"] == "1", r.text
            assert "concurrent renders: expected at most 1" in r.json()["detail"]
        assert len(calls) == 1  # none of them was estimated
        release.set()
        t.join(60)
        assert first["r"].status_code == 503 and app.state.service.limits.total == 0
        entered.clear()
        t = threading.Thread(target=lambda: first.setdefault("s", http.post("/v1/stores/v/render", json=body)))
        t.start()
        assert entered.wait(60)
        release.set()
        t.join(60)
        assert len(calls) == 1  # the same request on the same store: its estimate was kept


def test_the_weights_bits_scale_the_estimate(served_store):
    """M3: ``digits`` 9 (30-bit trilinear weights) costs three times the default 3 (10 bits);
    nearest weights are unaffected; a packed store's ``weight_bits`` 16 costs 1.6 times its 8."""
    cam = hevr.Camera.orbit(CT, azimuth=30, elevation=20, width=64, height=64)
    b = Budget()
    three = b.check(_ct(), RenderRequest(view=cam, channel="vector", sampling="trilinear", digits=3))
    nine = b.check(_ct(), RenderRequest(view=cam, channel="vector", sampling="trilinear", digits=9))
    assert (three.bits, nine.bits) == (10, 30) and nine.products == 3 * three.products
    assert "30-bit weights" in nine.describe() and "bit" not in three.describe()
    near = [
        b.check(_ct(), RenderRequest(view=cam, channel="vector", sampling="nearest", digits=d)).products for d in (3, 9)
    ]
    assert near[0] == near[1]
    packing = types.SimpleNamespace(weight_bits=8)
    pk = types.SimpleNamespace(
        meta=types.SimpleNamespace(packing=packing, store_id=None), shape=CT, spacing=(1.0, 1.0, 1.0), level=0
    )
    eight = b.check(pk, RenderRequest(view=cam, channel="scalar", sampling="trilinear", tile=8))
    sixteen = b.check(pk, RenderRequest(view=cam, channel="scalar", sampling="trilinear", tile=8, weight_bits=16))
    assert eight.products == 64 * 64 * 512 * 4 and sixteen.products == -(-eight.products * 16 // 10)


def test_a_request_cannot_choose_another_backend(served_store, no_render):
    """M3: a request's ``backend`` other than the server's is refused (422 naming it), before any work."""
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]), backend="cpu")
    with TestClient(app) as http:
        for endpoint in ("render", "stream"):
            r = http.post(f"/v1/stores/v/{endpoint}", json=_body(served_store.ev, 8, 8, backend="auto"))
            assert r.status_code == 422, r.text
            assert r.json()["detail"] == "backend: expected null or 'cpu' (this server's), got 'auto'"
        assert app.state.service.limits.total == 0


def test_the_stats_header_tells_nothing_of_other_tokens(served_store):
    """L3: the render cache is shared across tokens, so the header has no ``reused_ray_sums`` nor
    ``map_tasks`` (0 for a reused render): the same view twice answers the same keys."""
    app = create_app(open_stores([str(served_store.dir / "v.zarr")]))
    with TestClient(app) as http:
        body = _body(served_store.ev, 8, 8)
        seen = [json.loads(http.post("/v1/stores/v/render", json=body).headers["x-hevr-stats"]) for _ in range(2)]
    assert set(seen[0]) == set(seen[1]) and set(seen[0]) <= set(jobs.STATS), seen
    assert "reused_ray_sums" not in seen[1] and "map_tasks" not in seen[1]


def test_one_parser_for_counts():
    """The CLI's ``--max-products`` and the Dask config's keys read "8e9" alike (budget.parse_count)."""
    from hevr.cli.serve import products_type

    assert products_type("8e9") == parse_count("k", "8e9", 2**62) == 8 * 10**9
    with dask.config.set({"hevr.serve.max-products": "8e9"}):
        assert Budget.from_config().max_products == 8 * 10**9
    for bad in ("8.5", "0", "x", "1e30"):
        with pytest.raises(hevr.ParameterError):
            parse_count("k", bad, 2**62)
