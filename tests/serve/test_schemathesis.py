"""A bounded schemathesis run against ``hevr serve`` (issue 48, item 4): requests generated from
the OpenAPI document (:mod:`hevr.serve.openapi`, itself generated from :mod:`hevr.remote.schema`),
each answer checked against the same document.

Checked for every case: no 5xx; the status, the content type, the JSON body and the headers are
ones the document declares for the operation; every failure is a problem document
(``application/problem+json``, its ``status`` the answer's). Positive cases are valid by the
schema (most still fail the domain checks or the planner: a 4xx naming the field, never a 5xx);
negative cases break the schema and must be refused (4xx).

What it costs (:data:`EXAMPLES` cases per operation and mode, about 500 requests a pass): the
in-process pass (the app under Starlette's test client, an 8³ phantom under a 256-bit key, no
cluster: Dask's synchronous scheduler, the planner capped at 256 pixels) about 5-10 s; the pass
against a real ``hevr serve`` subprocess (one worker, the same caps) about 10-20 s, marked
``slow``; measured on a loaded 2-core machine. Both are derandomised: the same cases every run.
"""

from __future__ import annotations

import json
import time

import dask
import pytest
import schemathesis
from _serving import hevr_serve
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from hypothesis.errors import Unsatisfiable
from schemathesis.checks import (
    content_type_conformance,
    negative_data_rejection,
    not_a_server_error,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

import hevr
from hevr.remote.protocol import PROBLEM_MEDIA
from hevr.serve.app import create_app
from hevr.serve.tokens import TokenTable, hash_token, new_token

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    response_headers_conformance,
]
LIMITS = {"hevr.limits.max-pixels": 256, "hevr.limits.max-samples": 1 << 16}
EXAMPLES = 50  # per operation and generation mode


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, keypair256):
    """An 8³ verifiable store served by the in-process app under the name ``tiny``."""
    _, priv = keypair256
    path = tmp_path_factory.mktemp("schemathesis") / "tiny.zarr"
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(hevr.phantom(8), str(path), priv, brick=4, verifiable=True, progress=False)
    return ev, path


def _integers(value):
    """Integral floats as integers (7.0 -> 7): the JSON Schema ``integer`` takes 7.0, the parser
    does not (tests/remote/test_protocol.py), and a number field takes either."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        return int(value)
    if isinstance(value, list):
        return [_integers(v) for v in value]
    if isinstance(value, dict):
        return {k: _integers(v) for k, v in value.items()}
    return value


def _problem(response) -> None:
    if response.status_code >= 400:
        assert response.headers["content-type"][0].startswith(PROBLEM_MEDIA), response.headers
        if response.request.method == "HEAD":  # the head of the GET's answer: no body to read
            assert not response.content, response.content[:80]
            return
        doc = response.json()
        assert doc["status"] == response.status_code and isinstance(doc["detail"], str), doc


def _tokens(path=None):
    """A token of a table that may render every store (the document asks for the bearer token:
    a server with a token table, as the document describes it); its file written at ``path``."""
    token = new_token()
    doc = {
        "version": 1,
        "tokens": [{"name": "schemathesis", "sha256": hash_token(token), "stores": ["*"], "concurrent": 4}],
    }
    if path is not None:
        path.write_text(json.dumps(doc))
    return token, TokenTable.from_dict(doc)


def _authorise(case, token: str, positive: bool) -> None:
    """The server's token in place of the generated one; a case without the header (a negative
    case that leaves it out) keeps it out: the server must answer 401. /v1/health asks for none."""
    headers = dict(case.headers or {})
    if "Authorization" in headers or (positive and case.operation.path != "/v1/health"):
        headers["Authorization"] = f"Bearer {token}"
        case.headers = headers


def run(schema, stores: list[str], counts: dict, token: str) -> None:
    """Every operation of ``schema``, positive and negative cases, the ``{store}`` of most cases one
    of ``stores`` (else the generated one: an unknown store's 404), with the server's ``token``."""
    for result in schema.get_all_operations():
        op = result.ok()
        for mode in schemathesis.GenerationMode:
            checks = CHECKS + ([negative_data_rejection] if mode.is_negative else [])

            @settings(
                max_examples=EXAMPLES,
                deadline=None,
                database=None,
                derandomize=True,
                phases=[Phase.explicit, Phase.generate],
                suppress_health_check=list(HealthCheck),
            )
            @given(case=op.as_strategy(generation_mode=mode), store=st.sampled_from([*stores, None]))
            def one(case, store):  # called at once below, in this iteration: its loop variables are current
                if store and "store" in (case.path_parameters or {}):
                    case.path_parameters = {**case.path_parameters, "store": store}
                if mode.is_positive and isinstance(case.body, dict):  # noqa: B023 (runs in this iteration)
                    case.body = _integers(case.body)
                _authorise(case, token, mode.is_positive)  # noqa: B023 (runs in this iteration)
                response = case.call()
                key = f"{op.label} {mode.value}"  # noqa: B023 (runs in this iteration)
                counts.setdefault(key, {}).setdefault(response.status_code, 0)
                counts[key][response.status_code] += 1
                case.validate_response(response, checks=checks)  # noqa: B023 (runs in this iteration)
                _problem(response)

            try:
                one()
            except Unsatisfiable:  # nothing to break (no parameters, no body): no negative cases
                assert mode.is_negative, op.label


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
@pytest.mark.timeout(300)
def test_schemathesis_in_process(tiny):
    ev, path = tiny
    token, table = _tokens()
    app = create_app({"tiny": hevr.open_volume(str(path))}, tokens=table)
    schema = schemathesis.openapi.from_asgi("/v1/openapi.json", app, headers={"Authorization": f"Bearer {token}"})
    counts: dict = {}
    t0 = time.perf_counter()
    with dask.config.set({"scheduler": "sync", **LIMITS}):
        run(schema, ["tiny", ev.meta.store_id], counts, token)
    print(f"{time.perf_counter() - t0:.1f} s", counts)
    answered = {code for c in counts.values() for code in c}
    # the run reached past the store lookup: renders answered, and bodies refused by name
    assert 200 in answered and 400 in answered and 404 in answered, counts
    assert any(200 in c for key, c in counts.items() if "/render" in key or "/stream" in key), counts


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_schemathesis_against_hevr_serve(tiny, tmp_path):
    ev, path = tiny
    token, _ = _tokens(tmp_path / "tokens.json")
    env = {"DASK_HEVR__LIMITS__MAX_PIXELS": "256", "DASK_HEVR__LIMITS__MAX_SAMPLES": str(1 << 16)}
    with hevr_serve(str(path), "--workers", "1", "--tokens", str(tmp_path / "tokens.json"), env=env) as (
        url,
        proc,
        lines,
    ):
        schema = schemathesis.openapi.from_url(f"{url}/v1/openapi.json", headers={"Authorization": f"Bearer {token}"})
        counts: dict = {}
        run(schema, ["tiny", ev.meta.store_id], counts, token)
        assert proc.poll() is None, "\n".join(lines[-40:])
    assert any(200 in c for key, c in counts.items() if "/render" in key), counts
