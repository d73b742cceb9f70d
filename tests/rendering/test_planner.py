"""hevr.rendering.planning.planner: refuses what could overflow, accepts what fits, tiny keys decrypt right;
plan_render's bounds against brute force and hand-computed values."""

from __future__ import annotations

import itertools
import json
import math
import warnings
from fractions import Fraction

import numpy as np
import pytest

import hevr
from hevr.core.limits import integrity_bits
from hevr.crypto.keys import generate_keypair
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import brick_grid, brick_weights
from hevr.rendering.planning.modes import combination_matrix, make_spec
from hevr.rendering.planning.planner import RenderPlan, plan_render
from hevr.store.metadata import ChannelInfo, VolumeMetadata

SHAPE = (6, 7, 8)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        pub, priv = generate_keypair(64)
    rng = np.random.default_rng(11)
    vol = rng.integers(0, 256, SHAPE).astype(np.uint8)
    ev = hevr.encrypt_volume(
        vol,
        tmp_path_factory.mktemp("p") / "v.zarr",
        priv,
        brick=(3, 4, 4),
        vector_dims=3,
        vector_digits=2,
        progress=False,
    )
    return ev, vol, priv


def test_64_bit_key_refuses_high_precision(tiny):  # the reciprocal's precision: server finishing
    ev, _, _ = tiny
    cam = hevr.Camera.orbit(ev, width=8, height=8)
    with pytest.raises(hevr.RenderPlanError, match="precision") as info:
        hevr.render(ev, cam, sampling="trilinear", precision=15, progress=False, finish="server")
    assert "64-bit key" in str(info.value)
    with pytest.raises(hevr.RenderPlanError):
        hevr.render(
            ev,
            cam,
            mode="tf",
            nodes=[(0.2, "red"), (0.9, "blue")],
            sampling="trilinear",
            precision=8,
            comb_digits=8,
            progress=False,
            finish="server",
        )


@pytest.mark.parametrize("mode, kw", [("xray", {}), ("emphasize", {"density": 0.4})])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_64_bit_key_accepts_feasible_render_and_decrypts_right(tiny, mode, kw, sampling):
    ev, vol, priv = tiny
    cam = hevr.Camera.orbit(ev, azimuth=20, elevation=10, width=8, height=8)
    img = hevr.render(ev, cam, mode=mode, sampling=sampling, precision=2, digits=2, comb_digits=2, progress=False, **kw)
    got = img.decrypt(priv)
    ref = hevr.render_plain(vol, cam, mode=mode, sampling=sampling, vector_dims=3, **kw)
    bound = hevr.rendering.encrypted.error_bound(ev, cam, mode, sampling, digits=2, precision=2, comb_digits=2, **kw)
    assert np.all(np.abs(got - ref) <= bound)


def test_signed_volume_uses_public_offset(tmp_path, keypair256):
    pub, priv = keypair256
    rng = np.random.default_rng(2)
    vol = rng.integers(-1000, 1000, SHAPE).astype(np.int16)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", pub, brick=(3, 4, 4), progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=45, width=9, height=7)
    img = hevr.render(ev, cam, sampling="trilinear", progress=False)
    assert img.offset > 0 and img.per_pack > 1
    got = img.decrypt(priv)
    ref = hevr.render_plain(vol, cam, sampling="trilinear", value_range=ev.value_range)
    assert np.all(np.abs(got - ref) <= hevr.rendering.encrypted.error_bound(ev, cam, "xray", "trilinear"))
    assert got.min() < 0  # negative pixel values survive packing


def test_plan_bounds_are_recorded(tiny):
    ev, _, _ = tiny
    img = hevr.render(ev, hevr.Camera.orbit(ev, width=6, height=6), precision=2, progress=False)
    plan = img.info["plan"]
    assert int(plan["bound"]) < 2 ** plan["pack_bits"]
    assert plan["per_pack"] * plan["pack_bits"] + integrity_bits(64) <= 64 - 1


# -- plan_render directly: bounds against brute force and hand-computed values ------------------

BIG_N = 2**2047 + 1  # plan_render reads n only through n // 3 and n's bit length


SCALAR = ChannelInfo(exponent=0)
VECTOR = ChannelInfo(exponent=-3, digits=3, dims=4)


def _meta(value_range=(0.0, 255.0), scalar=SCALAR, vector=VECTOR):
    return VolumeMetadata(
        shape=(4, 4, 4),
        spacing=(1.0, 1.0, 1.0),
        brick=(2, 2, 2),
        n="1",
        fingerprint="",
        ciphertext_bytes=0,
        dtype="uint8",
        value_range=value_range,
        scalar=scalar,
        vector=vector,
    )


def _plan(
    n=BIG_N,
    *,
    mode="xray",
    sampling="nearest",
    density=None,
    nodes=None,
    n_samples=(0, 1, 2, 3),
    digits=0,
    precision=2,
    comb_digits=2,
    pack=True,
    meta=None,
    vector_dims=4,
):
    spec = make_spec(mode, sampling, 1.0, density, nodes, vector_dims)
    comb = combination_matrix(spec, vector_dims) if mode != "xray" else None
    return plan_render(
        n=n,
        spec=spec,
        meta=meta or _meta(),
        n_samples=np.asarray(n_samples),
        digits=digits,
        precision=precision,
        comb_digits=comb_digits,
        pack=pack,
        combination=comb,
    )


def _recip(G: int, n_r: int, K: int) -> int:
    """round(10^G / (n_r K)), half up, in exact arithmetic."""
    return math.floor(Fraction(10**G, n_r * K) + Fraction(1, 2)) if n_r else 0


def test_hand_computed_xray_plan():
    """uint8, nearest, n_r <= 3, precision 2: G = 2 + ceil(log10 3) = 3, every W_r·R_r <=
    10^3 + 3, bound = 255·1003 = 255765 (18 bits), (255 - 64) // 18 = 10 values per 256-bit
    ciphertext (64 bits kept for the integrity check)."""
    plan = _plan(2**255 + 1, precision=2)
    assert (plan.channel, plan.factor, plan.recip_digits, plan.offset) == ("scalar", 1, 3, 0)
    assert plan.bound == 255 * 1003 == 255765
    assert (plan.pack_bits, plan.per_pack) == (18, 10)
    assert plan.exponent == -3 and plan.channels_out == 1 and plan.comb is None


def test_hand_computed_tf_exponent():
    """tf, trilinear, 2 weight digits, vector digits 3, comb_digits 4, two nodes (K = 2),
    n_r <= 7, precision 1: G = 1 + ceil(log10 14) = 3 and the exponent is -2 - 3 - 4 - 3."""
    plan = _plan(
        mode="tf",
        sampling="trilinear",
        nodes=[(0.25, "red"), (0.75, "blue")],
        n_samples=(7, 0, 5),
        digits=2,
        precision=1,
        comb_digits=4,
    )
    assert (plan.channel, plan.factor, plan.recip_digits, plan.channels_out) == ("vector", 2, 3, 3)
    assert plan.exponent == -12 and plan.weight_exponent == -2 and plan.channel_exponent == -3
    spec = make_spec("tf", "trilinear", 1.0, None, [(0.25, "red"), (0.75, "blue")], 4)
    expected = np.rint(combination_matrix(spec, 4) * 10**4).astype(np.int64)
    assert plan.comb == tuple(tuple(int(x) for x in row) for row in expected)
    assert len(plan.comb) == 4 and all(len(r) == 3 for r in plan.comb)


@pytest.mark.parametrize(
    "n_max, precision, G", [(1, 2, 2), (9, 2, 3), (10, 2, 3), (11, 2, 4), (100, 0, 2), (101, 0, 3)]
)
def test_reciprocal_digits(n_max, precision, G):
    """G = precision + ceil(log10(max n_r)), so 10^G >= 10^precision · n_r for every pixel."""
    plan = _plan(n_samples=(0, n_max), precision=precision)
    assert plan.recip_digits == G and 10**G >= 10**precision * n_max


def test_reciprocals_are_rounded_half_up():
    plan = _plan(mode="tf", nodes=[(0.1, "red"), (0.5, "green"), (0.9, "blue")], n_samples=(0, 1, 2, 7), precision=1)
    assert (plan.factor, plan.recip_digits) == (3, 3)  # 1 + ceil(log10 21)
    assert plan.reciprocal(np.array([0, 1, 2, 7])) == [0, 333, 167, 48]  # 1000/3, 1000/6, 1000/21
    tie = _plan(n_samples=(4,), precision=0)  # G = 1: 10/4 = 2.5 rounds up
    assert tie.reciprocal(np.array([4])) == [3]
    for n_r in range(1, 8):
        r = plan.reciprocal(np.array([n_r]))[0]
        assert r == _recip(3, n_r, 3)
        assert abs(Fraction(r * n_r * 3, 10**3) - 1) <= Fraction(5, 10 ** (plan.precision + 1))


@pytest.mark.parametrize("precision", [0, 1, 2])
def test_nearest_bound_against_brute_force(precision):
    """Every reachable ray sum of every pixel enumerated (sample values -3..5, n_r up to 7; the
    sums of n_r values are built up sample by sample): the packed value M + O of each lies in
    [0, bound], and the bound is not loose by more than the planner's own modelling (max |value|
    on both sides) plus the reciprocal's rounding. n_r = 6 makes R_r·n_r exceed 10^G."""
    lo, hi = -3, 5
    n_samples = (0, 1, 2, 3, 6, 7)
    plan = _plan(n_samples=n_samples, precision=precision, meta=_meta(value_range=(float(lo), float(hi))))
    G = plan.recip_digits
    sums = {0}
    packed_all = []
    for n_r in range(1, max(n_samples) + 1):
        sums = {s + v for s in sums for v in range(lo, hi + 1)}
        if n_r in n_samples:
            R = _recip(G, n_r, 1)
            packed_all += [R * s + plan.offset for s in sums]
    assert min(packed_all) >= 0 and max(packed_all) <= plan.bound
    assert plan.bound < 2**plan.pack_bits
    wr = [n_r * _recip(G, n_r, 1) for n_r in n_samples[1:]]
    if precision == 0:
        assert max(wr) > 10**G  # the case that needs the planner's + n_max slack
    need_offset = -lo * max(wr)
    model = max(abs(lo), hi) * max(wr) + need_offset
    assert plan.offset >= need_offset and plan.bound <= model * (1 + 2 * 10**-precision)


def _ray_weight_sums(shape, cam, digits):
    """W_r: the trilinear integer weights of every (ray, voxel) pair, summed over all bricks."""
    rays = cast_rays(cam, shape, (1.0, 1.0, 1.0), 1.0)
    W = np.zeros(rays.n_rays, dtype=np.int64)
    for idx in itertools.product(*(range(g) for g in brick_grid(shape, 2))):
        bw = brick_weights(rays, shape, (1.0, 1.0, 1.0), 2, idx, "trilinear", 1.0, digits=digits)
        for r, a, b in zip(bw.rays, bw.indptr[:-1], bw.indptr[1:]):
            W[r] += int(bw.weights[a:b].sum())
    return rays, W


@pytest.mark.parametrize("digits", [0, 1, 2])
def test_trilinear_bound_against_real_weights(digits):
    """The real rounded weights of a small view: W_r <= n_r·(10^d + 4), and the largest
    reachable mantissa (every voxel at the top of its range) stays within the bound."""
    shape = (3, 4, 5)
    cam = Camera.orbit(shape, azimuth=30, elevation=20, width=6, height=5)
    rays, W = _ray_weight_sums(shape, cam, digits)
    ns = rays.n_samples
    assert ns.max() > 0
    assert np.all(W <= ns * (10**digits + 4))
    xray = _plan(sampling="trilinear", digits=digits, n_samples=ns, precision=1)
    reach = max(255 * int(w) * _recip(xray.recip_digits, int(n), 1) for w, n in zip(W, ns))
    assert reach <= xray.bound
    nodes = [(0.2, "red"), (0.8, (0.5, 0.5, 1.0))]
    tf = _plan(mode="tf", nodes=nodes, sampling="trilinear", digits=digits, n_samples=ns, precision=1)
    colsum = np.asarray(tf.comb).sum(axis=0)  # Σ_k Q[k, c], every S_k at 10^3 · W_r
    reach_tf = max(int(c) * 10**3 * int(w) * _recip(tf.recip_digits, int(n), 2) for w, n in zip(W, ns) for c in colsum)
    assert reach_tf <= tf.bound and tf.offset == 0


def test_float_scalar_range_is_floored_and_ceiled():
    """value_range (-1.234, 2.501) at exponent -2: mantissas in [floor(-123.4), ceil(250.1)] = [-124, 251]."""
    meta = _meta(value_range=(-1.234, 2.501), scalar=ChannelInfo(exponent=-2, digits=2))
    plan = _plan(meta=meta, n_samples=(1, 2), precision=0)  # G = 1, W_r·R_r <= 10 + 2
    assert plan.channel_exponent == -2 and plan.exponent == -2 - 1
    assert plan.offset == 124 * 12 and plan.bound == 251 * 12 + 124 * 12


def test_empty_view_plans_nothing():
    plan = _plan(n_samples=np.zeros(6, np.int64), precision=3)
    assert (plan.bound, plan.offset, plan.recip_digits) == (0, 0, 3)


def _smallest_key_bits(bound: int) -> int:
    """The fewest bits of n for which a plan of this bound is accepted: bits(bound) <= bits(n) - 1 - κ."""
    return next(k for k in range(2, 4096) if bound.bit_length() <= k - 1 - integrity_bits(k))


@pytest.mark.parametrize("bits", [64, 128, 254, 256, 272, 512, 1024, 2048, 3072])
def test_packing_capacity_follows_key_size(bits):
    """The smallest modulus of each size: per_pack slots of pack_bits fill at most
    bits - 1 - κ (κ = 64 from 256 bits, a quarter of a toy key's bits), one more would not
    fit, so a packed plaintext is below n / 2^κ."""
    n = 2 ** (bits - 1) + 1
    kappa = integrity_bits(bits)
    room = bits - 1 - kappa
    plan = _plan(n, precision=2)
    assert kappa == (64 if bits >= 256 else bits // 4)
    assert 2 ** (plan.pack_bits - 1) <= plan.bound < 2**plan.pack_bits  # pack_bits is minimal
    assert plan.per_pack == room // plan.pack_bits
    assert plan.per_pack * plan.pack_bits <= room < (plan.per_pack + 1) * plan.pack_bits
    assert 2 ** (plan.per_pack * plan.pack_bits + kappa) <= n
    unpacked = _plan(n, precision=2, pack=False)
    assert (unpacked.per_pack, unpacked.pack_bits, unpacked.bound) == (1, 0, plan.bound)


@pytest.mark.parametrize("precision", [3, 60])
def test_refusal_threshold_keeps_the_integrity_margin(precision):
    """The bound does not depend on n; a plan is accepted iff the bound needs at most
    bits(n) - 1 - κ bits (far below n/3): accepted at the smallest such key, refused one bit below."""
    bound = _plan(precision=precision).bound
    k = _smallest_key_bits(bound)
    ok = _plan(2 ** (k - 1), precision=precision)
    assert ok.bound == bound and ok.per_pack == 1
    n_bad = 2 ** (k - 2) + 1  # one bit short
    assert bound < n_bad // 3
    with pytest.raises(hevr.RenderPlanError) as info:
        _plan(n_bad, precision=precision)
    msg = str(info.value)
    assert "normalised mantissa" in msg and f"a {k - 1}-bit key" in msg and "integrity" in msg
    for knob in ("larger key", "precision=", "digits=", "comb_digits="):
        assert knob in msg
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("value_range, amax", [((0.0, 255.0), 255), ((-1000.0, 1.0), 1000)])
def test_ray_sum_overflow_is_named_first(value_range, amax):
    """|S| <= max(|lo|, |hi|)·W_r: a negative ray sum must also stay above -n/3."""
    meta = _meta(value_range=value_range)
    s_bound = amax * 50
    plan = _plan(n_samples=(50,), precision=0, meta=meta)
    assert plan.bound > s_bound
    with pytest.raises(hevr.RenderPlanError, match=f"the ray sum could reach {s_bound.bit_length()} bits"):
        _plan(3 * s_bound, n_samples=(50,), precision=0, meta=meta)


@pytest.mark.parametrize(
    "knob, small, large",
    [
        ("precision", {"precision": 1}, {"precision": 4}),
        ("digits", {"sampling": "trilinear", "digits": 1}, {"sampling": "trilinear", "digits": 4}),
        (
            "comb_digits",
            {"mode": "tf", "nodes": [(0.3, "red")], "comb_digits": 1},
            {"mode": "tf", "nodes": [(0.3, "red")], "comb_digits": 5},
        ),
    ],
)
def test_turning_the_named_knob_makes_a_refused_render_fit(knob, small, large):
    """For a key between the two bounds the large setting is refused and the small one fits."""
    lo_bound = _plan(**small).bound
    hi_bound = _plan(**large).bound
    assert lo_bound < hi_bound
    assert lo_bound.bit_length() < hi_bound.bit_length()
    n = 2 ** (_smallest_key_bits(lo_bound) - 1)  # room for exactly lo_bound's bits
    assert _plan(n, **small).bound == lo_bound
    with pytest.raises(hevr.RenderPlanError, match=f"{knob}="):
        _plan(n, **large)


def test_plan_dict_round_trip():
    plan = _plan(
        mode="tf",
        nodes=[(0.25, "red"), (0.75, "blue")],
        sampling="trilinear",
        digits=2,
        n_samples=(3, 9),
        meta=_meta(value_range=(-1000.0, 1000.0)),
    )
    d = json.loads(json.dumps(plan.to_dict()))
    assert isinstance(d["bound"], str) and isinstance(d["offset"], str)
    assert RenderPlan.from_dict(d) == plan
    signed = _plan(meta=_meta(value_range=(-1000.0, 1000.0)), n_samples=(3, 9))
    assert signed.offset > 0 and RenderPlan.from_dict(json.loads(json.dumps(signed.to_dict()))) == signed
