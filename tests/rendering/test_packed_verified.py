"""Verified packed frames (hevr.rendering.packed.verified): verifiable by default, honest frames
verify and decrypt to the unverified picture, and every lie of a server ends in an error."""

from __future__ import annotations

import dataclasses
import logging

import dask
import numpy as np
import pytest

import hevr
from hevr.errors import IntegrityError, ParameterError, VerificationError
from hevr.rendering.packed import PackedImage, SlicePlan
from hevr.rendering.packed.verified import PackedVerification

SHAPE = (13, 9, 11)
SPACING = (1.0, 0.8, 1.3)


def cam(ev, az, el, w=14, h=11):
    return hevr.Camera.orbit(ev, azimuth=az, elevation=el, width=w, height=h, parallel=True)


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-verified") / "v.zarr"
    return hevr.encrypt_volume(volume, path, keypair256[1], brick=4, spacing=SPACING, layout="packed", progress=False)


def render(ev, camera, sampling="trilinear", **kw):
    return hevr.render(ev, camera, sampling=sampling, progress=False, **kw)


def test_verifiable_by_default(store, tmp_path, keypair256, volume, caplog):
    """A packed store encrypted with the private key carries tags unless the owner opts out; one
    encrypted with the public key cannot, and says so."""
    pub, priv = keypair256
    assert store.meta.tags and "scalar_tag" in store.meta.channel_names
    off = hevr.encrypt_volume(
        volume, tmp_path / "off.zarr", priv, brick=4, layout="packed", verifiable=False, progress=False
    )
    assert not off.meta.tags
    with caplog.at_level(logging.WARNING, logger="hevr"):
        public = hevr.encrypt_volume(volume, tmp_path / "pub.zarr", pub, brick=4, layout="packed", progress=False)
    assert not public.meta.tags and any("has no tags" in r.getMessage() for r in caplog.records)
    voxel = hevr.encrypt_volume(volume[:4, :4, :4], tmp_path / "vox.zarr", priv, brick=4, progress=False)
    assert not voxel.meta.tags  # per-voxel stores: unchanged
    with pytest.raises(ParameterError, match="verifiable: expected True, False or None"):
        hevr.encrypt_volume(volume, tmp_path / "bad.zarr", priv, layout="packed", verifiable="yes", progress=False)


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("view", [(90, 0), (60, 10), (120, -25), (250, 30)])
def test_honest_frames_verify(store, keypair256, volume, view, sampling):
    """The default render is verified; it decrypts, with require_verified, to the same exact sums
    and picture as the unverified render, within error_bound of the float64 slice reference."""
    priv = keypair256[1]
    c = cam(store, *view)
    img = render(store, c, sampling, tile=4)  # several tiles, several classes
    assert img.verified and isinstance(img.verification, PackedVerification) and img.n_ciphertexts > 0
    assert img.stats["verify"]["ops"]["map"] == img.stats["ops"]["map"]  # the same products on the tags
    arr = img.decrypt(priv, require_verified=True)
    assert np.array_equal(arr, img.decrypt(priv, require_verified=store.meta.store_id))
    plain = render(store, c, sampling, tile=4, verify=False)
    assert not plain.verified
    assert np.array_equal(img.decrypt_sums(priv), plain.decrypt_sums(priv))
    assert np.array_equal(img.decrypt_sums(priv), img.plan.plain_sums(volume.astype(np.int64) - store.packing.offset))
    ref = hevr.render_plain(volume, c, sampling=sampling, spacing=SPACING, slices=True)
    assert (np.abs(arr - ref) <= hevr.error_bound(store, c, sampling=sampling)).all()


def test_verify_arguments(store, tmp_path, keypair256, volume):
    priv = keypair256[1]
    c = cam(store, 90, 0)
    assert render(store, c, verify=True).verified
    assert render(store, c, verify=store.meta.store_id).verified
    with pytest.raises(VerificationError, match="expected the store 0123456789abcdef"):
        render(store, c, verify="0123456789abcdef")
    off = hevr.encrypt_volume(
        volume, tmp_path / "off.zarr", priv, brick=4, layout="packed", verifiable=False, progress=False
    )
    with pytest.raises(ParameterError, match="verify: expected a request that can be verified.*no tags"):
        render(off, c, verify=True)
    img = render(store, c)
    with pytest.raises(VerificationError, match="expected a frame of the store 0123456789abcdef"):
        img.decrypt(priv, require_verified="0123456789abcdef")
    with pytest.raises(ParameterError, match="require_verified: expected True, False, a store id or a hevr.Expect"):
        img.decrypt(priv, require_verified=1)


def _shift_slot(img, priv, delta_sign=-1):
    """A copy of ``img`` with one value's non-zero slot lowered by one: a well-formed ciphertext whose
    slots all stay within their bounds (the decoder cannot tell), as a lying server would send."""
    K = img.plan.packing.slot_bits
    n = img.n
    for t, recs in enumerate(img.ciphertexts):
        for i in range(len(recs)):
            v = int(priv.raw_decrypt(int.from_bytes(recs[i].tobytes(), "big")))
            for s in range(img.plan.slots_out):
                if (v >> (K * s)) & ((1 << K) - 1):
                    bad = [r.copy() for r in img.ciphertexts]
                    c = int.from_bytes(recs[i].tobytes(), "big")
                    c = c * pow(1 + n, (n + delta_sign * (1 << (K * s))) % n, n * n) % (n * n)
                    bad[t][i] = np.frombuffer(c.to_bytes(recs.shape[1], "big"), np.uint8)
                    return dataclasses.replace(img, ciphertexts=bad)
    raise AssertionError("no non-zero slot")


def test_lies_are_caught(store, keypair256, volume):
    """A value changed within its bounds, values of another view, another frame's aggregate, a
    tampered seed, altered metadata: VerificationError, never a picture."""
    priv = keypair256[1]
    c = cam(store, 60, 10)
    img = render(store, c)
    forged = _shift_slot(img, priv)
    with pytest.raises(VerificationError, match="does not verify"):
        forged.decrypt(priv)
    other = render(store, cam(store, 60, 12))  # another view's aggregate on this frame's values
    with pytest.raises(VerificationError):
        dataclasses.replace(img, verification=other.verification).decrypt(priv)
    again = render(store, c)  # the same view again: another seed, another aggregate
    with pytest.raises(VerificationError, match="does not verify"):
        dataclasses.replace(
            img, verification=dataclasses.replace(img.verification, seed=again.verification.seed)
        ).decrypt(priv)
    v = img.verification
    with pytest.raises(VerificationError, match="does not verify"):
        dataclasses.replace(img, verification=dataclasses.replace(v, aggregate=again.verification.aggregate)).decrypt(
            priv
        )
    meta = dataclasses.replace(v.meta, value_range=(0.0, 300.0))  # public metadata altered: the MAC fails
    with pytest.raises(VerificationError, match="owner's MAC"):
        dataclasses.replace(img, verification=dataclasses.replace(v, meta=meta)).decrypt(priv)
    plain = render(store, c, verify=False)  # another render of the same view holds the same values: it verifies
    assert np.array_equal(dataclasses.replace(plain, verification=v).decrypt(priv), img.decrypt(priv))


def test_no_picture_from_a_corrupted_verified_frame(store, keypair256):
    priv = keypair256[1]
    img = render(store, cam(store, 120, -25))
    for t in range(len(img.ciphertexts)):
        bad = PackedImage(**{**img.__dict__, "ciphertexts": [c.copy() for c in img.ciphertexts]})
        bad.ciphertexts[t][0, -3] ^= 0x40
        with pytest.raises((IntegrityError, VerificationError)):
            bad.decrypt(priv)


def test_resident_distributed_and_one_value_tiles(store, keypair256, cluster):
    """A resident volume's frame verifies too (the tags are streamed), with one value per tile, and
    on a distributed cluster."""
    priv = keypair256[1]
    c = cam(store, 250, 30)
    want = render(store, c, verify=False).decrypt(priv)
    with dask.config.set(scheduler="sync"):
        res = store.persist()
        img = render(res, c, tile=1)
    assert img.verified and img.stats["resident"] and img.plan.n_tiles > 4
    assert np.array_equal(img.decrypt(priv, require_verified=True), want)
    far = render(store, c, client=cluster)
    assert far.verified and np.array_equal(far.decrypt(priv, require_verified=True), want)


def test_render_frame_on_a_packed_store(store, keypair256, volume):
    """hevr.render_frame on a packed store: the verified X-ray as a Frame (one component), the
    same picture as render + decrypt, with the key holder's check timed."""
    priv = keypair256[1]
    c = cam(store, 60, 10)
    frame = hevr.render_frame(store, c, priv, sampling="trilinear", progress=False)
    assert isinstance(frame, hevr.Frame) and frame.channel == "scalar" and frame.components == 1
    assert frame.stats["verified"] and frame.stats["check_s"] >= 0 and frame.stats["map_tasks"] > 0
    want = render(store, c, verify=False).decrypt(priv)
    np.testing.assert_array_equal(frame.image, want)
    np.testing.assert_array_equal(frame.recolour("xray"), want)
    with pytest.raises(ParameterError, match="finish"):
        hevr.render_frame(store, c, priv, finish="client")


def test_weight_bits_16_verifies(tmp_path, keypair256):
    """The most in-slice weight bits a request may ask (16): a sample on a voxel weighs 2^16, and the
    key holder's check takes it (its coefficients stay exact)."""
    priv = keypair256[1]
    vol = np.random.default_rng(3).integers(0, 256, (8, 2, 256)).astype(np.uint8)  # K sized for x: 256
    ev = hevr.encrypt_volume(vol, tmp_path / "w.zarr", priv, brick=4, layout="packed", progress=False)
    c = hevr.Camera.orbit(ev, view="anterior", width=32, height=8, parallel=True)  # 2 slices along y
    img = render(ev, c, weight_bits=16)
    assert img.plan.weight_bits == 16 and img.verified
    arr = img.decrypt(priv, require_verified=True)
    np.testing.assert_array_equal(arr, render(ev, c, weight_bits=16, verify=False).decrypt(priv))


def test_a_plan_too_big_is_refused_before_it_is_built():
    """Metadata that claims millions of thin slices (anyone can write a checksum) is refused by the
    plan's own size check, before any table per slice is allocated."""
    from hevr.errors import RenderPlanError
    from hevr.store.packing import PackingInfo

    shape, spacing = (12, 2_000_000, 10), (1.0, 0.9 * 9 / 2_000_000, 1.2)
    c = hevr.Camera.orbit(shape, view="anterior", azimuth=20, width=13, height=11, parallel=True, spacing=spacing)
    info = PackingInfo(axis=0, slots=2, slot_bits=40, weight_bits=10, offset=0)
    with pytest.raises(RenderPlanError, match="expected a packed frame whose plan fits"):
        SlicePlan.build(c, shape, spacing, (4, 4, 4), info, "trilinear")
