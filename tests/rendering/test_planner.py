"""The overflow planner: refuses what could overflow, accepts what fits, tiny keys decrypt right."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import hevr
from hevr.crypto.keys import generate_keypair

SHAPE = (6, 7, 8)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        pub, priv = generate_keypair(64)
    rng = np.random.default_rng(11)
    vol = rng.integers(0, 256, SHAPE).astype(np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path_factory.mktemp("p") / "v.zarr", priv, brick=(3, 4, 4),
                             vector_dims=3, vector_digits=2, progress=False)
    return ev, vol, priv


def test_64_bit_key_refuses_high_precision(tiny):
    ev, _, _ = tiny
    cam = hevr.Camera.orbit(ev, width=8, height=8)
    with pytest.raises(hevr.RenderPlanError, match="precision") as info:
        hevr.render(ev, cam, sampling="trilinear", precision=15, progress=False)
    assert "64-bit key" in str(info.value)
    with pytest.raises(hevr.RenderPlanError):
        hevr.render(ev, cam, mode="tf", nodes=[(0.2, "red"), (0.9, "blue")], sampling="trilinear",
                    precision=8, comb_digits=8, progress=False)


@pytest.mark.parametrize("mode, kw", [("xray", {}), ("emphasize", {"density": 0.4})])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_64_bit_key_accepts_feasible_render_and_decrypts_right(tiny, mode, kw, sampling):
    ev, vol, priv = tiny
    cam = hevr.Camera.orbit(ev, azimuth=20, elevation=10, width=8, height=8)
    img = hevr.render(ev, cam, mode=mode, sampling=sampling, precision=2, digits=2, comb_digits=2,
                      progress=False, **kw)
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
    assert plan["per_pack"] * plan["pack_bits"] <= 64 - 2
