"""The OpenAPI document of ``hevr serve`` is generated from the protocol's models (issue 48, item
4): valid OpenAPI 3.1, exactly the app's routes, the bounds the code uses, no link to a missing
file, and its schemas agree with the parsers (what one accepts the other does, what one refuses
the other does, naming the field)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import dask
import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from openapi_spec_validator import validate
from starlette.routing import Route
from starlette.testclient import TestClient

import hevr
from hevr.image.header import MAX_INT_DIGITS
from hevr.remote import schema
from hevr.remote.protocol import (
    IMAGE_MEDIA,
    MAX_BODY,
    MAX_JSON_DEPTH,
    PROBLEM_MEDIA,
    UNITS_MEDIA,
    RenderRequest,
    VerifyRequest,
    parse_json,
)
from hevr.rendering.geometry.coordinates import MAX_COORDINATE
from hevr.rendering.geometry.plane import MAX_SLAB
from hevr.serve.app import create_app
from hevr.serve.openapi import ERRORS, openapi_document
from hevr.store.metadata import CHANNELS
from hevr.store.packing import MAX_WEIGHT_BITS
from hevr.volume.pyramid import MAX_LEVELS

ROOT = Path(__file__).resolve().parents[2]
DOC = openapi_document()
SCHEMAS = DOC["components"]["schemas"]
CAM = {"position": [0.0, 0.0, 40.0], "focal_point": [0.0, 0.0, 0.0], "width": 8, "height": 6}


def _validator(name: str) -> jsonschema.Draft202012Validator:
    """The JSON Schema validator of component ``name`` (its $refs resolved in the document)."""
    return jsonschema.Draft202012Validator({"$ref": f"#/components/schemas/{name}", "components": DOC["components"]})


@pytest.fixture(scope="module")
def app(tmp_path_factory, keypair256):
    pub, _ = keypair256
    path = tmp_path_factory.mktemp("openapi") / "tiny.zarr"
    with dask.config.set(scheduler="sync"):
        hevr.encrypt_volume(hevr.phantom(8), str(path), pub, brick=4, progress=False)
    return create_app({"tiny": hevr.open_volume(str(path))})


def test_the_document_is_valid_openapi_3_1():
    validate(DOC)
    assert DOC["openapi"].startswith("3.1") and openapi_document() == DOC and openapi_document() is not DOC


def test_the_app_serves_the_document_and_exactly_its_routes(app):
    """Every route and method, HEAD included (Starlette answers HEAD on every GET route; /v1/health
    asks for it by name), is documented, and nothing else is."""
    served = {(r.path, m) for r in app.routes if isinstance(r, Route) for m in r.methods}
    documented = {(path, m.upper()) for path, item in DOC["paths"].items() for m in item}
    assert ("/v1/health", "HEAD") in served and ("/v1/health", "HEAD") in documented
    assert served == documented
    with TestClient(app) as http:
        assert http.get("/v1/openapi.json").json() == json.loads(json.dumps(DOC))
        head = http.head("/v1/health")
        assert head.status_code == 200 and head.content == b""
        assert str(http.head("/v1/stores").status_code) in DOC["paths"]["/v1/stores"]["head"]["responses"]


def _titles() -> dict[int, set[str]]:
    """The problem titles ``hevr serve`` sends, by status, as its source writes them."""
    out: dict[int, set[str]] = {}
    for path in (ROOT / "hevr" / "serve").rglob("*.py"):
        for status, title in re.findall(r'Problem\(\s*(\d{3}),\s*"([^"]+)"', path.read_text(encoding="utf-8")):
            out.setdefault(int(status), set()).add(title)
    return out


def test_every_problem_the_server_sends_is_documented():
    """Each title the server's code sends under a status is in that status's description (review
    L5: 422 lacked the budget's refusal, 429 the work in flight, 503 cancelled renders and shutdown)."""
    titles = _titles()
    assert {"render over the server's budget", "render refused by the planner"} <= titles[422], titles
    assert {"too many concurrent renders", "too much work in flight"} <= titles[429], titles
    assert {"render cancelled", "server shutting down"} <= titles[503], titles
    for status, said in titles.items():
        assert status in ERRORS, status
        for title in said:
            assert title in ERRORS[status], (status, title)
    posted = DOC["paths"]["/v1/stores/{store}/render"]["post"]["responses"]
    for name in ("step", "tile", "products", "--max-pixels", "--max-token-products"):
        assert name in posted["422"]["description"], name
    assert "Retry-After" in posted["429"]["headers"] and "Retry-After" in posted["503"]["headers"]


def test_the_protocols_doc_has_the_documents_statuses():
    """docs/protocol.md's table of failures says what the document says, status by status."""
    text = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\| (\d{3}) \| (.*) \|$", text, re.M))
    assert {int(c): t for c, t in rows.items()} == ERRORS


def test_security_is_the_token_unless_the_server_has_none():
    """One requirement, the bearer token (an empty alternative would make it optional on every
    server); the description says a server without a token table asks for none."""
    assert DOC["security"] == [{"bearer": []}]
    assert "without" in DOC["components"]["securitySchemes"]["bearer"]["description"]
    assert "token table" in DOC["info"]["description"]
    for method in ("get", "head"):
        assert DOC["paths"]["/v1/health"][method]["security"] == []


def test_every_operation_documents_its_answers():
    for path, item in DOC["paths"].items():
        for method, op in item.items():
            answers = op["responses"]
            assert "200" in answers and "500" in answers, (path, method)
            for code, answer in answers.items():
                if code != "200" and method != "head":
                    assert int(code) in ERRORS and list(answer["content"]) == [PROBLEM_MEDIA], (path, code)
            if method == "post":
                assert {"400", "401", "404", "413", "415", "422", "429", "503"} <= set(answers), path
            if method == "head":
                assert set(answers) == set(item["get"]["responses"]), path
                assert not any("content" in a for a in answers.values()), path
    render = DOC["paths"]["/v1/stores/{store}/render"]["post"]["responses"]["200"]["content"]
    assert set(render) == {IMAGE_MEDIA, UNITS_MEDIA}
    assert DOC["paths"]["/v1/health"]["get"]["security"] == []  # no token asked


def test_bounds_are_the_codes_own():
    props = SCHEMAS["RenderRequest"]["properties"]
    assert props["level"]["maximum"] == MAX_LEVELS  # was a hard-coded 8
    assert props["weight_bits"]["anyOf"][0]["maximum"] == MAX_WEIGHT_BITS
    assert props["step"]["maximum"] == schema.MAX_STEP and props["tile"]["maximum"] == schema.MAX_SIDE
    assert props["channel"]["enum"] == list(CHANNELS)
    assert props["backend"]["anyOf"][0]["enum"] == [*schema.BACKENDS]
    camera, plane = SCHEMAS["Camera"]["properties"], SCHEMAS["Plane"]["properties"]
    assert camera["position"]["items"]["maximum"] == MAX_COORDINATE and camera["width"]["maximum"] == schema.MAX_SIDE
    assert camera["view_angle"]["default"] == hevr.Camera((0, 0, 1), (0, 0, 0)).view_angle
    assert plane["slab"]["maximum"] == MAX_SLAB and plane["kind"]["const"] == "plane"
    for name in ("Camera", "Plane", "RenderRequest", "VerifyRequest", "Store", "Stores", "Version", "Health"):
        assert SCHEMAS[name]["additionalProperties"] is False, name
    assert SCHEMAS["Store"]["required"] == ["id", "name", "metadata"]


def test_the_protocols_doc_has_the_models_tables():
    """docs/protocol.md's field tables are :func:`~hevr.remote.schema.field_table`'s, between
    ``<!-- fields: NAME -->`` and ``<!-- end fields -->`` (rewrite them from it when a model changes)."""
    text = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    tables = dict(re.findall(r"<!-- fields: (\w+) -->\n(.*?)\n<!-- end fields -->", text, re.S))
    assert set(tables) == {"RenderRequest", "Camera", "Plane", "VerifyRequest"}
    for number in (MAX_BODY, MAX_INT_DIGITS, MAX_JSON_DEPTH):  # the parser's bounds, as the prose says them
        assert f"at most {number} " in text, number
    for name, table in tables.items():
        assert table == schema.field_table(getattr(schema, name)), name


def test_no_link_to_a_missing_file():
    text = json.dumps(DOC)
    files = set(re.findall(r"(?<![\w/.-])[\w.-]+(?:/[\w.-]+)*\.(?:md|py)\b", text))  # not a URL's path
    assert files, "the document names no file (the test would check nothing)"
    for name in files:
        assert (ROOT / name).exists() or (ROOT / "hevr" / name).exists(), name


@pytest.mark.parametrize(
    "name, parse", [("RenderRequest", RenderRequest.from_dict), ("VerifyRequest", VerifyRequest.from_dict)]
)
def test_the_documents_examples_are_accepted_and_round_trip(name, parse):
    examples = SCHEMAS[name]["examples"]
    assert examples
    for example in examples:
        _validator(name).validate(example)
        req = parse(parse_json(json.dumps(example).encode(), "body"))
        assert parse(req.to_dict()) == req
        _validator(name).validate(json.loads(json.dumps(req.to_dict())))


views = st.one_of(
    st.builds(
        lambda az, w, h, par: hevr.Camera((40.0 * az, 1.0, 30.0), (0.0, 0.0, 0.0), width=w, height=h, parallel=par),
        st.floats(-1, 1),
        st.integers(1, 64),
        st.integers(1, 64),
        st.booleans(),
    ),
    st.builds(
        lambda w, h, slab, sp: hevr.Plane((0, 0, 1), (1, 0, 0), (0, 1, 0), w, h, pixel_spacing=sp, slab=slab),
        st.integers(1, 64),
        st.integers(1, 64),
        st.integers(1, 9),
        st.floats(0.01, 10),
    ),
)
requests = st.builds(
    lambda view, **kw: RenderRequest(view=view, **{**kw, "level": 0 if isinstance(view, hevr.Plane) else kw["level"]}),
    view=views,
    channel=st.sampled_from(schema.CHANNELS),
    sampling=st.sampled_from(schema.SAMPLINGS),
    step=st.floats(0.01, schema.MAX_STEP),
    level=st.integers(0, MAX_LEVELS),
    digits=st.integers(0, schema.MAX_DIGITS),
    pack=st.booleans(),
    tile=st.integers(1, schema.MAX_SIDE),
    backend=st.sampled_from([None, *schema.BACKENDS]),
    weight_bits=st.none() | st.integers(0, MAX_WEIGHT_BITS),
)


@settings(max_examples=60, deadline=None)
@given(requests, st.binary(min_size=32, max_size=32))
def test_what_the_client_sends_the_document_accepts(req, seed):
    wire = json.loads(json.dumps(req.to_dict()))
    _validator("RenderRequest").validate(wire)
    _validator("VerifyRequest").validate(json.loads(json.dumps(VerifyRequest(req, seed).to_dict())))
    assert RenderRequest.from_dict(wire) == req


@pytest.mark.parametrize(
    "change, match",
    [
        ({"colour": "red"}, r"request: expected only the fields .*got extra fields \['colour'\]"),
        ({"view": dict(CAM, colour="red")}, r"view: expected only the fields .*got extra fields \['colour'\]"),
        ({"view": dict(CAM, width=schema.MAX_SIDE + 1)}, r"view\.width: expected an integer in \[1, 4096\], got 4097"),
        ({"view": dict(CAM, position=[0, 0, True])}, r"view\.position\[2\]: expected a number"),
        ({"view": dict(CAM, position=[0, 0])}, r"view\.position: expected an array of 3 items"),
        (
            {"view": {"kind": "plane", "origin": [0, 0, 0]}},
            r"view: expected the fields .*missing \['height', 'u', 'v', ",
        ),
        ({"view": "camera"}, r"view: expected a Camera object or a Plane object, got 'camera'"),
        ({"channel": "secret"}, r"channel: expected one of scalar, vector, gradient, got 'secret'"),
        ({"step": "1"}, r"step: expected a number in \(0, 1e\+06\], got '1'"),
        ({"step": 2e6}, "step: expected a number in"),
        ({"level": MAX_LEVELS + 1}, rf"level: expected an integer in \[0, {MAX_LEVELS}\], got {MAX_LEVELS + 1}"),
        ({"level": True}, "level: expected an integer"),
        ({"pack": 1}, "pack: expected true or false, got 1"),
        ({"backend": "gpu"}, "backend: expected one of auto, .* or null, got 'gpu'"),
        ({"weight_bits": MAX_WEIGHT_BITS + 1}, "weight_bits: expected an integer in"),
    ],
)
def test_what_the_document_refuses_the_parser_refuses_by_name(change, match):
    body = {"view": CAM, "channel": "scalar", **change}
    assert not _validator("RenderRequest").is_valid(body)
    with pytest.raises(hevr.ParameterError, match=match):
        RenderRequest.from_dict(body)
    field = match.split(":")[0]
    with pytest.raises(hevr.ParameterError, match="^render" if field == "request" else rf"^render\.{field}:"):
        VerifyRequest.from_dict({"render": body, "seed": "00" * 32})


def test_integers_are_written_as_integers():
    """JSON Schema's ``integer`` takes 7.0; the parser, strict since before the schema, does not
    (the document says so in its description)."""
    body = {"view": CAM, "channel": "scalar", "level": 1.0}
    assert _validator("RenderRequest").is_valid(body)
    with pytest.raises(hevr.ParameterError, match="level: expected an integer in .*got 1.0"):
        RenderRequest.from_dict(body)
    assert "1.0" in DOC["info"]["description"]
