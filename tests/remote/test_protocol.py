"""hevr.remote.protocol: strict requests (round trips, unknown fields and bounds) and frames."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr
from hevr.remote.protocol import (
    MAX_BODY,
    MAX_SIDE,
    RenderRequest,
    VerifyRequest,
    pack_frame,
    parse_json,
    unpack_head,
)

CAM = {"position": [0.0, 0.0, 40.0], "focal_point": [0.0, 0.0, 0.0], "width": 8, "height": 6}

requests = st.builds(
    RenderRequest,
    view=st.builds(
        lambda az, w, h: hevr.Camera((40.0 * az, 1.0, 30.0), (0.0, 0.0, 0.0), width=w, height=h),
        st.floats(-1, 1),
        st.integers(1, 64),
        st.integers(1, 64),
    ),
    channel=st.sampled_from(["scalar", "vector", "gradient"]),
    sampling=st.sampled_from(["nearest", "trilinear"]),
    step=st.floats(0.01, 100),
    level=st.integers(0, 8),
    digits=st.integers(0, 9),
    pack=st.booleans(),
    tile=st.integers(1, MAX_SIDE),
    backend=st.sampled_from([None, "auto", "cpu", "cuda-host", "cuda"]),
)


@settings(max_examples=60, deadline=None)
@given(requests)
def test_requests_round_trip_through_json(req):
    wire = json.dumps(req.to_dict()).encode()
    back = RenderRequest.from_dict(parse_json(wire, "body"))
    assert back == req and back.key() == req.key()


@settings(max_examples=30, deadline=None)
@given(requests, st.binary(min_size=32, max_size=32))
def test_verify_requests_round_trip(req, seed):
    v = VerifyRequest(render=req, seed=seed)
    assert VerifyRequest.from_dict(parse_json(json.dumps(v.to_dict()).encode(), "body")) == v


@pytest.mark.parametrize(
    "change, match",
    [
        ({"view": dict(CAM, width=MAX_SIDE + 1)}, "width"),
        ({"view": dict(CAM, colour="red")}, r"view: .*extra fields \[.colour.\]"),
        ({"view": [1, 2, 3]}, "view"),
        ({"channel": "scalar_tag"}, "channel"),
        ({"sampling": "cubic"}, "sampling"),
        ({"step": 0}, "step"),
        ({"step": "1"}, "step"),
        ({"step": True}, "step"),
        ({"level": 9}, "level"),
        ({"level": 1.0}, "level"),
        ({"digits": -1}, "digits"),
        ({"tile": 0}, "tile"),
        ({"pack": 1}, "pack"),
        ({"backend": "gpu"}, "backend"),
        ({"density": 0.5}, "extra fields"),
        ({"nodes": [[0.1, "red"]]}, "extra fields"),
    ],
)
def test_requests_refuse_by_name(change, match):
    with pytest.raises(hevr.ParameterError, match=match):
        RenderRequest.from_dict({"view": CAM, "channel": "scalar", **change})


def test_planes_and_seeds():
    plane = hevr.Plane((0, 0, 0), (1, 0, 0), (0, 1, 0), 4, 4).to_dict()
    req = RenderRequest.from_dict({"view": plane, "channel": "scalar"})
    assert isinstance(req.view, hevr.Plane)
    with pytest.raises(hevr.ParameterError, match="plane"):
        RenderRequest.from_dict({"view": plane, "channel": "scalar", "level": 1})
    for seed in ("ab" * 31, "AB" * 32, 5, "zz" * 32):
        with pytest.raises(hevr.ParameterError, match="seed"):
            VerifyRequest.from_dict({"render": {"view": CAM, "channel": "scalar"}, "seed": seed})


def test_parse_json_bounds():
    with pytest.raises(hevr.ParameterError, match="at most"):
        parse_json(b" " * (MAX_BODY + 1), "body")
    for raw in (b'{"a": NaN}', b'{"a": Infinity}', b'{"a": 1' + b"0" * 50 + b"}", b"\xff", b"[" * 40 + b"]" * 40):
        with pytest.raises(hevr.ParameterError):
            parse_json(raw, "body")


def test_frames():
    assert unpack_head(pack_frame(7, b"x" * 300)[:8]) == (7, 300)


# -- a request built in Python: every refusal a ParameterError naming the field (review H4: it was
# a KeyError, the schema helper knew only the wire models, not RenderOptions)
PY_CAM = hevr.Camera((0.0, 0.0, 40.0), (0.0, 0.0, 0.0), width=8, height=6)
OPTIONS = ("channel", "sampling", "step", "level", "digits", "pack", "tile", "backend", "weight_bits")


@pytest.mark.parametrize(
    "change, match",
    [
        ({"step": -1.0}, r"^step: expected a number in \(0, 1e\+06\], got -1.0$"),
        ({"tile": 0}, rf"^tile: expected an integer in \[1, {MAX_SIDE}\], got 0$"),
        ({"digits": 99}, r"^digits: expected an integer in \[0, 9\], got 99$"),
        ({"channel": "bogus"}, r"^channel: expected one of scalar, vector, gradient, got 'bogus'$"),
        ({"step": True}, r"^step: expected a number .*got True$"),
        ({"step": float("nan")}, r"^step: expected a number .*got nan$"),
        ({"level": np.int64(99)}, r"^level: expected an integer in \[0, 8\], got 99$"),
    ],
)
def test_a_request_built_in_python_is_refused_by_name(change, match):
    with pytest.raises(hevr.ParameterError, match=match):
        RenderRequest(view=PY_CAM, **{"channel": "scalar", **change})


anything = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats()
    | st.text(max_size=20)
    | st.sampled_from([np.int64(3), np.float64("nan"), np.float32(1.5), np.bool_(True), 2**70, -0.0, 1e999]),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=6,
)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(OPTIONS), anything)
def test_any_field_value_is_accepted_or_refused_by_name(name, value):
    """Whatever a caller passes for a field: a request, or a ParameterError naming that field
    (never a KeyError, TypeError, ...); what is accepted round-trips through the wire."""
    kwargs = {"channel": "scalar", name: value}
    try:
        req = RenderRequest(view=PY_CAM, **kwargs)
    except hevr.ParameterError as exc:
        assert str(exc).startswith(f"{name}: expected "), str(exc)
    else:
        assert RenderRequest.from_dict(parse_json(json.dumps(req.to_dict()).encode(), "body")) == req
