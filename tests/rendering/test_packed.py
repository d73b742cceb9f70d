"""Packed frames (hevr.rendering.packed): exact slot sums, the float64 slice reference within
error_bound, the per-voxel picture, slot safety, refusals, integrity, backends and residency."""

from __future__ import annotations

import logging

import dask
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hevr
from hevr.errors import IntegrityError, KeyMismatchError, ParameterError, RenderPlanError, VerificationError
from hevr.rendering.packed import PackedImage, ShearGeometry, SlicePlan

SHAPE = (13, 9, 11)  # z (packing axis) not a multiple of the slots (S = 4 at 256 bits)
SPACING = (1.0, 0.8, 1.3)
# parallel views around the packing axis z (azimuth 90 looks along x; elevation tilts towards y),
# and views that lean towards z but not beyond 45°
VIEWS = [(90, 0), (90, 35), (270, -20), (60, 10), (120, -25), (250, 30), (300, 5)]
SAMPLINGS = ["nearest", "trilinear"]


def cam(ev, az, el, w=14, h=11, **kw):
    return hevr.Camera.orbit(ev, azimuth=az, elevation=el, width=w, height=h, parallel=True, **kw)


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(11).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-render") / "p.zarr"
    return hevr.encrypt_volume(volume, path, keypair256[1], brick=4, spacing=SPACING, layout="packed", progress=False)


def render(ev, camera, sampling, **kw):
    kw.setdefault("progress", False)
    kw.setdefault("verify", False)
    return hevr.render(ev, camera, sampling=sampling, **kw)


@pytest.mark.parametrize("sampling", SAMPLINGS)
@pytest.mark.parametrize("view", VIEWS)
def test_exact_sums_and_reference(store, keypair256, volume, view, sampling):
    """The decrypted slot sums are the exact integers of the same plan on the plaintext, and the
    frame lies within error_bound of the independent float64 slice reference."""
    priv = keypair256[1]
    c = cam(store, *view)
    img = render(store, c, sampling)
    assert isinstance(img, PackedImage) and img.shape == (11, 14)
    assert store.packing.slots == 4 and store.grid == (4, 3, 3)  # bricks of 4 (1 pack) × 4 × 4
    sums = img.decrypt_sums(priv)
    assert (sums == img.plan.plain_sums(volume.astype(np.int64) - store.packing.offset)).all()
    arr = img.decrypt(priv)
    ref = hevr.render_plain(volume, c, sampling=sampling, spacing=SPACING, slices=True)
    bound = hevr.error_bound(store, c, sampling=sampling)
    assert arr.shape == ref.shape == bound.shape
    assert (np.abs(arr - ref) <= bound).all()
    assert ref.max() > 10  # the view sees the volume
    ops = img.stats["ops"]
    assert ops["pairs"] > 0 and img.stats["layout"] == "packed"


@pytest.mark.parametrize("sampling", SAMPLINGS)
def test_zoomed_camera(store, keypair256, volume, sampling):
    """A camera that sees part of the volume: the blocks' slots of rays outside the frame hold real
    sums (checked against their own bounds, not counted), and the frame is exact and within the bound."""
    import dataclasses

    priv = keypair256[1]
    for view in ((90, 10), (60, 10)):
        c = cam(store, *view, w=9, h=7)
        c = dataclasses.replace(c, parallel_scale=c.parallel_scale / 4)
        img = render(store, c, sampling)
        assert img.plan.geometry.size[0] < SHAPE[0]  # fewer rays along z than the volume has
        assert (img.decrypt_sums(priv) == img.plan.plain_sums(volume.astype(np.int64) - store.packing.offset)).all()
        ref = hevr.render_plain(volume, c, sampling=sampling, spacing=SPACING, slices=True)
        assert (np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(store, c, sampling=sampling)).all()


@pytest.mark.parametrize("axis, view", [("y", dict(azimuth=30, elevation=0)), ("x", dict(azimuth=0, elevation=25))])
def test_other_packing_axes(tmp_path, keypair256, volume, axis, view):
    """Stores packed along y or x: exact sums, and within the bound of the reference for that axis."""
    priv = keypair256[1]
    ev = hevr.encrypt_volume(
        volume, tmp_path / "o.zarr", priv, brick=4, spacing=SPACING, layout="packed", pack_axis=axis, progress=False
    )
    c = hevr.Camera.orbit(ev, width=13, height=11, parallel=True, **view)
    for sampling in SAMPLINGS:
        img = render(ev, c, sampling)
        assert (img.decrypt_sums(priv) == img.plan.plain_sums(volume.astype(np.int64) - ev.packing.offset)).all()
        ref = hevr.render_plain(volume, c, sampling=sampling, spacing=SPACING, slices=axis)
        assert (np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(ev, c, sampling=sampling)).all()


def test_one_product_serves_S_rays(store, keypair256):
    """An orbit around the packing axis needs one class (no combine) and about 1/S of the per-voxel
    store's products: one multiplication per pack and slice (nearest)."""
    c = cam(store, 90, 20)
    img = render(store, c, "nearest")
    plan = img.plan
    assert plan.classes == 1 and img.stats["ops"]["combine_squarings"] == 0
    ni, nj = plan.geometry.size
    per_voxel_pairs = int(plan.geometry.sample_counts("nearest").sum())  # one product per ray sample
    assert img.stats["ops"]["pairs"] * store.packing.slots <= per_voxel_pairs * 1.6


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    shape=st.tuples(st.integers(2, 9), st.integers(2, 7), st.integers(2, 7)),
    az=st.floats(45.5, 134.5),
    el=st.floats(-80, 80),
    flip=st.booleans(),
    sampling=st.sampled_from(SAMPLINGS),
    brick=st.integers(2, 5),
    seed=st.integers(0, 2**16),
)
def test_hypothesis_views_and_shapes(tmp_path_factory, keypair256, shape, az, el, flip, sampling, brick, seed):
    """Any shape (ragged packs, multi-brick), any view the store serves: exact sums, within the bound."""
    priv = keypair256[1]
    vol = np.random.default_rng(seed).integers(0, 256, shape).astype(np.uint8)
    path = tmp_path_factory.mktemp("hyp") / "h.zarr"
    ev = hevr.encrypt_volume(vol, path, priv, brick=brick, layout="packed", progress=False)
    c = hevr.Camera.orbit(ev, azimuth=az + (180 if flip else 0), elevation=el, width=9, height=8, parallel=True)
    try:
        ShearGeometry.of(c, shape, (1, 1, 1), axis=0)
    except ParameterError:  # a view within 45° of z (large elevations tilt towards y, not z: rare)
        with pytest.raises(ParameterError, match="principal axis"):
            render(ev, c, sampling)
        return
    img = render(ev, c, sampling)
    assert (img.decrypt_sums(priv) == img.plan.plain_sums(vol.astype(np.int64) - ev.packing.offset)).all()
    ref = hevr.render_plain(vol, c, sampling=sampling, slices=True)
    assert (np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(ev, c, sampling=sampling)).all()


def test_same_picture_as_per_voxel():
    """The packed frame's slice sampling shows the per-voxel trilinear X-ray's picture: mean absolute
    difference under 1 % of the value range (phantom, views around z and leaning towards it)."""
    vol = hevr.phantom(40)
    for az, el in [(90, 0), (60, 15), (250, 30)]:
        c = hevr.Camera.orbit(vol.shape, azimuth=az, elevation=el, width=48, height=48, parallel=True)
        per_voxel = hevr.render_plain(vol, c, sampling="trilinear")
        for sampling in SAMPLINGS:
            sliced = hevr.render_plain(vol, c, sampling=sampling, slices=True)
            assert np.abs(per_voxel - sliced).mean() / 255 < 0.01


def test_refusals(store):
    """Everything a packed store does not serve is refused before any work, naming the option."""
    c = cam(store, 90, 0)
    with pytest.raises(ParameterError, match="camera: expected a parallel camera"):
        render(store, hevr.Camera.orbit(store, azimuth=90), "nearest")
    with pytest.raises(ParameterError, match="principal axis is not the packing axis 0 .z.*pack_axis"):
        render(store, cam(store, 0, 0), "nearest")  # the default orbit looks down z
    with pytest.raises(ParameterError, match="mode: expected 'xray'"):
        hevr.render(store, c, mode="tf", nodes=[(0.5, "red")], progress=False)
    with pytest.raises(ParameterError, match="step: expected 1.0"):
        render(store, c, "nearest", step=0.5)
    with pytest.raises(ParameterError, match="level"):
        render(store, c, "nearest", level=1)
    with pytest.raises(ParameterError, match="finish: expected 'client'"):
        render(store, c, "nearest", finish="server")
    with pytest.raises(ParameterError, match="compute: expected True"):
        render(store, c, "nearest", compute=False)
    with pytest.raises(ParameterError, match="plane: expected a plane perpendicular to the packing axis"):
        hevr.render_slice(store, hevr.Plane.oblique(store, normal=(1, 0, 1)), progress=False)
    with pytest.raises(ParameterError, match="packed store"):
        hevr.build_pyramid(store, 1, progress=False)
    with pytest.raises(ParameterError, match="slices: expected mode='xray'"):
        hevr.render_plain(np.zeros(SHAPE), c, gradient=True, slices=True)


def test_unverified_default_warns(tmp_path, keypair256, volume, caplog):
    """A packed store without tags (opted out) renders unverified by default, saying so on every render."""
    ev = hevr.encrypt_volume(
        volume, tmp_path / "u.zarr", keypair256[1], brick=4, layout="packed", verifiable=False, progress=False
    )
    assert not ev.meta.tags
    for _ in range(2):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="hevr"):
            img = hevr.render(ev, cam(ev, 90, 0), progress=False)
        assert not img.verified and any("not verified" in r.getMessage() for r in caplog.records)


def test_slot_safety_worst_case(tmp_path, keypair256):
    """All voxels at the top of the range and a view whose rays take the most samples of the longest
    axis: the largest slot sums the store was sized for decrypt exactly; more weight bits are refused."""
    priv = keypair256[1]
    shape = (7, 5, 9)  # longest non-packing axis: x (9)
    vol = np.full(shape, 255, np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path / "w.zarr", priv, brick=4, layout="packed", progress=False)
    K = ev.packing.slot_bits
    for sampling, view in (("trilinear", (90, 0)), ("nearest", (90, 0)), ("trilinear", (80, 13))):
        c = cam(ev, *view)
        img = render(ev, c, sampling)
        sums = img.decrypt_sums(priv)
        assert (sums == img.plan.plain_sums(np.full(shape, 255, np.int64))).all()
        if sampling == "trilinear" and view == (90, 0):
            assert int(sums.max()) == 255 * (1 << 10) * 9 and int(sums.max()).bit_length() == K  # the top slot bit
        inter = img.decrypt_intermediate(priv)  # rays whose every sample lies inside: the top value
        n = img.plan.geometry.sample_counts(sampling)
        inside = (n > 0) & (img.plan.contributing_slices() == n)
        tol = 2 * 255 / img.plan.unit if sampling == "trilinear" else 0.0  # the rounded weights' sum: U ± 2
        assert inside.sum() >= 4 and (np.abs(inter[inside] - 255.0) <= tol).all()
    with pytest.raises(RenderPlanError, match="weight_bits: expected in-slice weights"):
        render(ev, cam(ev, 90, 0), "trilinear", weight_bits=11)


def test_integrity(store, keypair256, keypair512):
    priv = keypair256[1]
    img = render(store, cam(store, 60, 10), "trilinear")
    with pytest.raises(KeyMismatchError):
        img.decrypt(keypair512[1])
    with pytest.raises(VerificationError, match="require_verified"):
        img.decrypt(priv, require_verified=True)  # rendered with verify=False
    for t in range(len(img.ciphertexts)):  # a flipped byte anywhere: an error, never a picture
        bad = PackedImage(**{**img.__dict__, "ciphertexts": [c.copy() for c in img.ciphertexts]})
        bad.ciphertexts[t][0, -3] ^= 0x40
        with pytest.raises(IntegrityError):
            bad.decrypt(priv)
    # a well-formed ciphertext of a value in the frame's slots but above a ray's largest sum
    from hevr.crypto.records import mpz_to_bytes

    bad = PackedImage(**{**img.__dict__, "ciphertexts": [c.copy() for c in img.ciphertexts]})
    K = store.packing.slot_bits
    bad.ciphertexts[0][0] = mpz_to_bytes([priv.public_key.encrypt((1 << K) - 1)], store.meta.ciphertext_bytes)[0]
    with pytest.raises(IntegrityError, match="slot"):
        bad.decrypt(priv)
    bad.ciphertexts = bad.ciphertexts[:-1]
    with pytest.raises(IntegrityError):
        bad.decrypt(priv)


def test_resident_and_distributed(store, keypair256, cluster):
    """Streamed, resident and on a distributed cluster: the same ciphertexts."""
    c = cam(store, 120, -25)
    base = render(store, c, "trilinear")
    with dask.config.set(scheduler="sync"):
        res = store.persist()
        again = render(res, c, "trilinear")
    assert again.stats["resident"] and not base.stats["resident"]
    far = render(store, c, "trilinear", client=cluster)
    res2 = store.persist(client=cluster)
    res2.resident.wait()
    near = render(res2, c, "trilinear", client=cluster)
    assert near.stats["resident"]
    for other in (again, far, near):
        assert all((a == b).all() for a, b in zip(base.ciphertexts, other.ciphertexts))
    assert np.array_equal(near.decrypt(keypair256[1]), base.decrypt(keypair256[1]))


def test_cuda_host_backend_identical(store):
    """The host-compiled CUDA kernels run the packed products and the Horner combine: identical bytes."""
    from hevr.backends import get_backend

    try:
        get_backend("cuda-host")
    except Exception as exc:  # pragma: no cover - a machine without a C compiler
        pytest.skip(f"cuda-host unavailable: {exc}")
    c = cam(store, 250, 30)
    for sampling in SAMPLINGS:
        a = render(store, c, sampling, backend="cpu")
        b = render(store, c, sampling, backend="cuda-host")
        assert b.stats["backend"] == "cuda-host"
        assert all((x == y).all() for x, y in zip(a.ciphertexts, b.ciphertexts))


def test_plan_is_public_and_small(store):
    """The plan is built from public parameters only and pickles small (it travels in every task)."""
    import pickle

    c = cam(store, 60, 10)
    plan = SlicePlan.build(c, store.shape, store.spacing, store.brick, store.packing, "trilinear")
    assert len(pickle.dumps(plan)) < 20_000
    tiles = set()
    for idx in store.brick_indices():
        keys, local, w = plan.brick_pairs(idx)
        assert (np.diff(keys) >= 0).all() and (w > 0).all()
        assert set(plan.tile_of(keys).tolist()) <= set(plan.brick_tiles(idx))
        tiles |= set(plan.brick_tiles(idx))
    assert tiles <= set(range(plan.n_tiles))


def test_reference_refuses_bad_slices():
    c = hevr.Camera.orbit(SHAPE, azimuth=90, width=5, height=5, parallel=True)
    vol = np.zeros(SHAPE)
    for bad in ("w", 3, 1.0, None, [0]):
        with pytest.raises(ParameterError, match="slices: expected True, False or a packing axis"):
            hevr.render_plain(vol, c, slices=bad)
    with pytest.raises(ParameterError, match="slices: expected mode='xray', step=1"):
        hevr.render_plain(vol, c, step="1", slices=True)
    assert hevr.render_plain(vol, c, slices="z").shape == (5, 5)


def test_resident_packed_store_costs_its_records(store):
    """persist plans a packed store's memory by its packed records (S voxels each), not its voxels."""
    with dask.config.set(scheduler="sync"):
        res = store.persist()
    width = store.meta.ciphertext_bytes
    records = int(np.prod(store.packing.array_shape(store.shape)))
    from hevr.backends import get_backend

    assert res.resident.nbytes == records * get_backend(res.resident.backend).residue_bytes(width)
