"""Issue 24 items 4 and 10: what a header or a request may say is bounded by what the
arithmetic can represent, checked where it enters; never a bare OverflowError,
ZeroDivisionError or ValueError from float arithmetic, and no data value in the message of an
error raised inside an encryption task."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hevr
from hevr.core.limits import FLOAT_MAX, fits_float
from hevr.errors import HevrError
from hevr.image.header import MAGIC
from hevr.rendering.planning.modes import combination_matrix, make_spec
from hevr.rendering.planning.planner import plan_render
from hevr.store.metadata import ChannelInfo, VolumeMetadata

HYPO = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def scene(tmp_path_factory, keypair256):
    _, priv = keypair256
    vol = np.random.default_rng(3).uniform(-50.0, 80.0, (6, 7, 8))
    ev = hevr.encrypt_volume(
        vol, tmp_path_factory.mktemp("b") / "v.zarr", priv, brick=4, value_range=(-50, 80), digits=2, progress=False
    )
    cam = hevr.Camera.orbit(ev, azimuth=20, elevation=10, width=6, height=5)
    img = hevr.render(ev, cam, progress=False)
    return ev, priv, cam, img


# -- item 4: the image exponent ----------------------------------------------------------------
def _rewrite(path, **fields) -> None:
    blob = path.read_bytes()
    (hl,) = struct.unpack_from("<I", blob, len(MAGIC))
    start = len(MAGIC) + 4
    head = json.loads(blob[start : start + hl])
    head.update(fields)
    raw = json.dumps(head, separators=(",", ":")).encode()
    data = MAGIC + struct.pack("<I", len(raw)) + raw + blob[start + hl : -32]
    path.write_bytes(data + hashlib.sha256(data).digest())


def test_an_exponent_inside_1000_that_overflows_float64_is_refused(scene, tmp_path):
    _, priv, _, img = scene
    path = tmp_path / "x.hevr"
    img.save(path)
    _rewrite(path, exponent=308)  # |exponent| <= 1000, but bound·10^308 > 1.8e308
    with pytest.raises(
        hevr.CorruptStoreError,
        match=r"header field 'exponent': expected an int with "
        r"max\(offset, bound − offset\)·10\^exponent <= 1\.798e\+308",
    ):
        hevr.load_image(path)
    with pytest.raises(hevr.IntegrityError, match="field 'exponent'"):
        dataclasses.replace(img, exponent=308).decrypt(priv)


def test_the_real_limit_is_the_largest_float(scene, keypair256):
    """The largest accepted exponent decrypts to finite values; one more is refused."""
    _, priv, _, img = scene
    top = max(img.offset, img.bound - img.offset)
    e = max(k for k in range(-1000, 1001) if fits_float(top, k))
    assert e < 308 and not fits_float(top, e + 1)
    assert np.isfinite(dataclasses.replace(img, exponent=e).decrypt(priv)).all()
    with pytest.raises(hevr.IntegrityError, match="exponent"):
        dataclasses.replace(img, exponent=e + 1).decrypt(priv)


@HYPO
@given(exponent=st.integers(-1000, 1000))
def test_any_header_exponent_decrypts_finite_or_is_refused(scene, exponent):
    _, priv, _, img = scene
    try:
        out = dataclasses.replace(img, exponent=exponent).decrypt(priv)
    except hevr.IntegrityError as exc:
        assert "exponent" in str(exc)
    else:
        assert np.isfinite(out).all()


# -- item 4: value_range at encryption and in the planner ---------------------------------------
def test_value_range_beyond_float_arithmetic_is_refused_before_anything_is_written(tmp_path, keypair256):
    vol = np.random.default_rng(1).uniform(0, 1, (4, 4, 4))
    for vr in [(-1e308, 1e308), (0, 1e101), (-(10**400), 1), (0, 10**5000), (float("inf"), 10**400)]:
        with pytest.raises(hevr.ParameterError, match=r"^value_range: expected .*\|lo\|, \|hi\| <= 1e\+100"):
            hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[1], brick=2, value_range=vr, progress=False)
        assert not (tmp_path / "v.zarr").exists()


def _meta(value_range, digits=3, vector=False):
    return VolumeMetadata(
        shape=(4, 4, 4),
        spacing=(1.0, 1.0, 1.0),
        brick=(2, 2, 2),
        n="1",
        fingerprint="",
        ciphertext_bytes=0,
        dtype="float64",
        value_range=value_range,
        scalar=ChannelInfo(exponent=-digits, digits=digits),
        vector=ChannelInfo(exponent=-3, digits=3, dims=4) if vector else None,
    )


def test_a_stores_huge_value_range_is_a_plan_error_not_an_overflow():
    """A store's metadata written before the bound (or by hand): the planner refuses it."""
    n = (1 << 4095) + 1  # a 4096-bit modulus: room for 1e308·10^30, but not for a float64 pixel
    spec = make_spec("xray", "nearest", 1.0, None, None, None)

    def plan(vr, precision=4):
        return plan_render(
            n=n,
            spec=spec,
            meta=_meta(vr, digits=30),
            n_samples=np.array([1, 5]),
            digits=3,
            precision=precision,
            comb_digits=4,
            pack=True,
            combination=None,
        )

    p = plan((-1e308, 1e308))  # exact mantissas; an average of such values is still a float64
    assert fits_float(max(p.offset, p.bound - p.offset), p.exponent)
    with pytest.raises(hevr.RenderPlanError, match=r"value_range: expected values whose render fits a float64"):
        plan((-1.5e308, 1.5e308), precision=0)  # the rounded reciprocal's margin (x1.5) passes 1.797e308
    with pytest.raises(hevr.RenderPlanError, match="bits"):
        plan_render(
            n=(1 << 1023) + 1,
            spec=spec,
            meta=_meta((-1e308, 1e308), digits=30),
            n_samples=np.array([5]),
            digits=3,
            precision=4,
            comb_digits=4,
            pack=True,
            combination=None,
        )


@HYPO
@given(
    lo=st.floats(-1e100, 1e100),
    width=st.floats(1e-300, 2e100),
    digits=st.integers(0, 30),
    mode=st.sampled_from(["xray", "emphasize", "tf"]),
    sampling=st.sampled_from(["nearest", "trilinear"]),
    wdigits=st.integers(0, 9),
    precision=st.integers(0, 30),
    comb_digits=st.integers(1, 12),
    n_max=st.integers(0, 2**53),
    density=st.floats(0, 1),
    bits=st.sampled_from([64, 256, 2048, 4096]),
)
def test_the_planner_plans_or_refuses_every_accepted_request(
    lo, width, digits, mode, sampling, wdigits, precision, comb_digits, n_max, density, bits
):
    hi = min(lo + width, 1e100)
    if not hi > lo:
        return
    vr = hevr.core.voxels.check_value_range((lo, hi))
    nodes = [(0.1, "red"), (density, "blue")] if mode == "tf" else None
    spec = make_spec(mode, sampling, 1.0, density if mode == "emphasize" else None, nodes, 4)
    comb = combination_matrix(spec, 4) if mode != "xray" else None
    n = (1 << (bits - 1)) + 1
    try:
        plan = plan_render(
            n=n,
            spec=spec,
            meta=_meta(vr, digits, vector=True),
            n_samples=np.array([n_max, 1]),
            digits=wdigits,
            precision=precision,
            comb_digits=comb_digits,
            pack=True,
            combination=comb,
        )
    except hevr.RenderPlanError:
        return
    assert fits_float(max(plan.offset, plan.bound - plan.offset), plan.exponent)


# -- item 10: the camera ----------------------------------------------------------------------
def test_a_camera_at_1e300_names_the_position():
    with pytest.raises(hevr.ParameterError, match=r"^position: expected coordinates of magnitude at most 1e\+12"):
        hevr.Camera((1e300, 1e300, 1e300), (0, 0, 0))
    with pytest.raises(hevr.ParameterError, match=r"^focal_point: expected coordinates"):
        hevr.Camera((0, 0, 5), (0, -1e200, 0))
    with pytest.raises(hevr.ParameterError, match=r"^view_up: expected coordinates"):
        hevr.Camera((0, 0, 5), (0, 0, 0), view_up=(0, 1e300, 0))
    with pytest.raises(hevr.ParameterError, match=r"^view_up: expected a vector of length at least 1e-09"):
        hevr.Camera((0, 0, 5), (0, 0, 0), view_up=(0, 1e-200, 0))
    with pytest.raises(hevr.ParameterError, match=r"^focal_point: expected a point at least"):
        hevr.Camera((1e9, 0, 0), (1e9 + 1e-4, 0, 0))
    with pytest.raises(hevr.ParameterError, match=r"^parallel_scale: expected a positive number of at most"):
        hevr.Camera((0, 0, 5), (0, 0, 0), parallel=True, parallel_scale=1e300)
    with pytest.raises(hevr.ParameterError, match=r"^distance: expected a positive number of at most"):
        hevr.Camera.orbit((4, 4, 4), distance=1e300)
    with pytest.raises(hevr.ParameterError, match=r"^spacing: expected a volume of at most"):
        hevr.Camera.orbit((4, 4, 4), spacing=(1e300, 1, 1))
    far = hevr.Camera.orbit((4, 4, 4), view_angle=1e-300)  # the default distance stops at 5e11
    assert np.isfinite(far.rays()[0]).all() and max(map(abs, far.position)) <= 1e12


coord = st.floats(allow_nan=False, allow_infinity=False)


@HYPO
@given(
    pos=st.tuples(coord, coord, coord),
    foc=st.tuples(coord, coord, coord),
    up=st.tuples(coord, coord, coord),
    parallel=st.booleans(),
)
def test_every_camera_is_refused_by_field_or_casts_finite_rays(pos, foc, up, parallel):
    try:
        cam = hevr.Camera(pos, foc, view_up=up, width=3, height=2, parallel=parallel)
    except hevr.ParameterError as exc:
        assert str(exc).split(":")[0] in ("position", "focal_point", "view_up", "parallel_scale")
        return
    origins, dirs = cam.rays()
    assert np.isfinite(origins).all() and np.isfinite(dirs).all()
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)


@HYPO
@given(x=st.floats(-1e12, 1e12), step=st.floats(1e-3, 1e13), spacing=st.floats(1e-3, 1e3))
def test_far_cameras_render_plain_or_refuse_by_field(x, step, spacing):
    vol = np.arange(27, dtype=np.float64).reshape(3, 3, 3)
    try:
        cam = hevr.Camera((x, 1.0, 2e3), (1.0, 1.0, 1.0), width=3, height=3)
        out = hevr.render_plain(vol, cam, step=step, spacing=(spacing,) * 3)
    except HevrError:
        return
    assert np.isfinite(out).all()


# -- item 10: no data value in an error raised inside a task -----------------------------------
def test_an_error_inside_an_encryption_task_quotes_no_data_value(tmp_path, keypair256, monkeypatch):
    """The owner's range check passes (here: it is told a narrower range, as when the input
    changes between the check and the tasks); the task that finds a value outside value_range
    names its brick, never the value nor the data range."""
    vol = np.full((4, 4, 4), 12.5)
    vol[3, 2, 1] = 31415.926
    monkeypatch.setattr("hevr.store.quantise.data_range", lambda v: (12.5, 12.5))
    for kw in [{}, {"vector_dims": 3}]:
        target = tmp_path / f"v{len(kw)}.zarr"
        with pytest.raises(hevr.ParameterError) as info:
            hevr.encrypt_volume(vol, target, keypair256[1], brick=2, value_range=(0, 100), progress=False, **kw)
        msg = str(info.value)
        assert msg.startswith("vol: brick (1, 1, 0): expected values inside value_range (0.0, 100.0)"), msg
        assert not any(s in msg for s in ("31415", "3.14", "12.5")), msg


def test_encode_density_names_where_not_what():
    with pytest.raises(hevr.ParameterError, match=r"got one outside \(or NaN\) at index \(1,\)") as info:
        hevr.encode_density(np.array([0.5, 1.2345678]), 3)
    assert "1.234" not in str(info.value)


def test_float_max_is_exact():
    assert float(FLOAT_MAX) == math.ldexp(1 - 2**-53, 1024) and fits_float(FLOAT_MAX, 0)
