"""Slices of packed stores (hevr.rendering.packed.planes, plane_image): exact slot values, the
float64 reference within error_bound, S pixels per ciphertext on planes containing the packing
axis, refusals before any work, the key holder's integrity checks, residency and a distributed cluster."""

from __future__ import annotations

import logging

import dask
import numpy as np
import pytest

import hevr
from hevr.errors import IntegrityError, KeyMismatchError, ParameterError, VerificationError
from hevr.rendering.packed.plane_image import PackedSlice
from hevr.rendering.packed.planes import PlanePlan

SHAPE = (13, 9, 11)  # z (packing axis) not a multiple of the slots (S = 4 at 256 bits): a ragged last pack
SPACING = (1.0, 0.8, 1.3)
SAMPLINGS = ["nearest", "trilinear"]


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-slices") / "p.zarr"
    return hevr.encrypt_volume(
        volume, path, keypair256[1], brick=4, spacing=SPACING, layout="packed", verifiable=False, progress=False
    )


def planes(ev):
    """Planes a z-packed store serves: perpendicular to z, and containing z's direction."""
    # normal -y, the pixel grid turned within the plane: one footprint per pixel
    rotated = hevr.Plane((1.0, 0.5, 2.0), (0.6, 0.0, 0.8), (-0.8, 0.0, 0.6), width=9, height=8)
    return {
        "axial": hevr.Plane.axial(ev, 5),
        "axial-between-packs": hevr.Plane.axial(ev, 3.4),  # layers 3 and 4: two packs
        "axial-slab": hevr.Plane.axial(ev, 6, slab=3, slab_step=0.7),
        "axial-zoomed": hevr.Plane.axial(ev, 8.2, width=7, height=5, pixel_spacing=0.6),
        "coronal": hevr.Plane.coronal(ev, 4),
        "sagittal": hevr.Plane.sagittal(ev, 3.3),
        "coronal-slab": hevr.Plane.coronal(ev, 4.2, slab=3, slab_step=0.6),
        "oblique-containing-z": hevr.Plane.oblique(ev, normal=(1, 1, 0), width=15, height=17),
        "coronal-rotated-grid": rotated,
        "oblique-fine": hevr.Plane.oblique(ev, normal=(1, -2, 0), pixel_spacing=0.45, width=12, height=30),
    }


def slice_(ev, plane, sampling, **kw):
    kw.setdefault("progress", False)
    kw.setdefault("verify", False)
    return hevr.render_slice(ev, plane, sampling=sampling, **kw)


@pytest.mark.parametrize("sampling", SAMPLINGS)
@pytest.mark.parametrize("name", list(planes(SHAPE)))
def test_exact_values_and_reference(store, keypair256, volume, name, sampling):
    """Every decrypted slot is the exact integer of the same plan on the plaintext, and the slice lies
    within error_bound of the independent float64 reference (render_slice_plain)."""
    priv = keypair256[1]
    plane = planes(store)[name]
    img = slice_(store, plane, sampling)
    assert isinstance(img, PackedSlice) and img.shape == (plane.height, plane.width)
    slots = img.decrypt_values(priv)
    assert np.array_equal(slots, img.plan.plain_values(volume.astype(np.int64) - store.packing.offset))
    arr = img.decrypt(priv)
    ref = hevr.render_slice_plain(volume, plane, sampling=sampling, spacing=SPACING)
    bound = hevr.error_bound(store, plane, sampling=sampling)
    assert arr.shape == ref.shape == bound.shape
    assert (np.abs(arr - ref) <= bound).all()
    assert ref.max() > 100 and img.hits.any()
    assert (arr[~img.hits] == 0).all() and (ref[~img.hits] == 0).all()
    if sampling == "nearest":  # an integer store: nearest slices are exact
        assert np.array_equal(arr, ref)
    else:
        assert bound.max() < 0.5  # 2·255/1024 per sample: a real bound, not a vacuous one


def test_nearest_axial_is_the_layer(store, keypair256, volume):
    """A nearest axial slice through layer k is vol[k] exactly, one pixel per ciphertext (one slot each)."""
    img = slice_(store, hevr.Plane.axial(store, 7), "nearest")
    assert np.array_equal(img.decrypt(keypair256[1]), volume[7].astype(np.float64))
    assert img.plan.kind == "perpendicular" and img.n_ciphertexts == SHAPE[1] * SHAPE[2]


@pytest.mark.parametrize("sampling", SAMPLINGS)
def test_containing_plane_serves_s_pixels_per_ciphertext(store, keypair256, volume, sampling):
    """On a coronal plane of a z-packed store every column of pixels shares its footprint: one
    ciphertext per column and pack (S = 4 pixels), not one per pixel."""
    plane = hevr.Plane.coronal(store, 2.5)
    img = slice_(store, plane, sampling)
    S = store.packing.slots
    assert img.plan.kind == "contains" and img.plan.n_footprints == plane.width
    assert img.n_ciphertexts == plane.width * -(-SHAPE[0] // S) < plane.width * plane.height / 3
    ref = hevr.render_slice_plain(volume, plane, sampling=sampling, spacing=SPACING)
    assert (np.abs(img.decrypt(keypair256[1]) - ref) <= hevr.error_bound(store, plane, sampling=sampling)).all()


@pytest.fixture(scope="module")
def store_x(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-slices-x") / "px.zarr"
    return hevr.encrypt_volume(
        volume,
        path,
        keypair256[1],
        brick=4,
        spacing=SPACING,
        layout="packed",
        pack_axis="x",
        verifiable=False,
        progress=False,
    )


@pytest.mark.parametrize("sampling", SAMPLINGS)
def test_store_packed_along_x(store_x, keypair256, volume, sampling):
    """Packed along x: sagittal planes are perpendicular to the axis, axial and coronal ones contain it."""
    for plane, kind in (
        (hevr.Plane.sagittal(store_x, 6.5), "perpendicular"),
        (hevr.Plane.axial(store_x, 4), "contains"),
        (hevr.Plane.coronal(store_x, 3.7), "contains"),
    ):
        img = slice_(store_x, plane, sampling)
        assert img.plan.kind == kind
        assert np.array_equal(
            img.decrypt_values(keypair256[1]), img.plan.plain_values(volume.astype(np.int64) - store_x.packing.offset)
        )
        ref = hevr.render_slice_plain(volume, plane, sampling=sampling, spacing=SPACING)
        assert (np.abs(img.decrypt(keypair256[1]) - ref) <= hevr.error_bound(store_x, plane, sampling=sampling)).all()
    with pytest.raises(ParameterError, match=r"^plane: .*packing axis x"):
        slice_(store_x, hevr.Plane.oblique(store_x, normal=(1, 0, 1)), "nearest")


def test_other_planes_refused_before_any_work(store, monkeypatch):
    """A plane that neither contains z nor is perpendicular to it: refused, naming plane and what
    serves it, before any brick is read."""

    def no_read(*a, **k):
        raise AssertionError("a brick was read")

    monkeypatch.setattr(type(store), "read_brick", no_read)
    for normal in ((1, 0, 1), (0, 0.1, 1), (0.3, -0.2, 0.9)):
        with pytest.raises(
            ParameterError,
            match=r"^plane: expected a plane perpendicular to the packing axis z or "
            r"containing its direction.*per-voxel store",
        ):
            slice_(store, hevr.Plane.oblique(store, normal=normal), "trilinear")


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"mode": "emphasize", "density": 0.5}, "^mode: expected 'xray' on a packed store"),
        ({"gradient": True}, "^density/nodes/gradient"),
        ({"finish": "server"}, "^finish: expected 'client'"),
        ({"verify": True}, "^verify: expected a request that can be verified, got the store has no tags"),
        ({"compute": False}, "^keep_sums/compute"),
    ],
)
def test_requests_refused(store, kw, match):
    with pytest.raises(ParameterError, match=match):
        slice_(store, hevr.Plane.axial(store, 2), "nearest", **kw)


def test_unverified_warns_and_require_verified(store, keypair256, caplog):
    """The default (verify=None) says the slice is not verified; require_verified refuses it."""
    with caplog.at_level(logging.WARNING, logger="hevr"):
        img = hevr.render_slice(store, hevr.Plane.axial(store, 1), progress=False)
    assert "not verified" in caplog.text
    assert not img.verified and "verified=False" in repr(img) and "key=" in repr(img)
    with pytest.raises(VerificationError, match="not verified"):
        img.decrypt(keypair256[1], require_verified=True)


@pytest.fixture(scope="module")
def verifiable(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-slices-verified") / "v.zarr"
    return hevr.encrypt_volume(volume, path, keypair256[1], brick=4, spacing=SPACING, layout="packed", progress=False)


@pytest.mark.parametrize("sampling", SAMPLINGS)
@pytest.mark.parametrize("name", ["axial-between-packs", "coronal-slab", "oblique-containing-z"])
def test_verified_slices(verifiable, keypair256, name, sampling):
    """A verifiable store's slices are verified by default: the same pixels as unverified, and a
    value changed within its bounds, or another slice's aggregate, is caught before any pixel."""
    import dataclasses

    priv = keypair256[1]
    plane = planes(verifiable)[name]
    img = hevr.render_slice(verifiable, plane, sampling=sampling, progress=False)
    assert img.verified and "verified=True" in repr(img)
    arr = img.decrypt(priv, require_verified=verifiable.meta.store_id)
    np.testing.assert_array_equal(arr, slice_(verifiable, plane, sampling).decrypt(priv))
    K = img.plan.packing.slot_bits
    n = img.n
    for t, recs in enumerate(img.ciphertexts):  # lower a non-zero slot by one: well-formed, within bounds
        vals = [int(priv.raw_decrypt(int.from_bytes(r.tobytes(), "big"))) for r in recs]
        hit = [(i, s) for i, v in enumerate(vals) for s in range(img.plan.packing.slots) if (v >> (K * s)) % (1 << K)]
        if hit:
            i, slot = hit[0]
            bad = [r.copy() for r in img.ciphertexts]
            c = int.from_bytes(recs[i].tobytes(), "big") * pow(1 + n, n - (1 << (K * slot)), n * n) % (n * n)
            bad[t][i] = np.frombuffer(c.to_bytes(recs.shape[1], "big"), np.uint8)
            with pytest.raises(VerificationError, match="does not verify"):
                dataclasses.replace(img, ciphertexts=bad).decrypt(priv)
            break
    else:
        raise AssertionError("no non-zero slot to lower")
    other = hevr.render_slice(verifiable, plane, sampling=sampling, progress=False)
    with pytest.raises(VerificationError, match="does not verify"):
        dataclasses.replace(
            img, verification=dataclasses.replace(img.verification, seed=other.verification.seed)
        ).decrypt(priv)


def _tampered(img, value, record):
    recs = [r.copy() for r in img.ciphertexts]
    recs[0][value] = record
    return PackedSlice(
        plan=img.plan,
        plane=img.plane,
        fingerprint=img.fingerprint,
        n=img.n,
        exponent=img.exponent,
        offset=img.offset,
        span=img.span,
        ciphertexts=recs,
        store_id=img.store_id,
    )


def _record(pub, m):
    return np.frombuffer(int(pub.encrypt(m)).to_bytes(pub.ciphertext_bytes, "big"), np.uint8)


def test_integrity_checks(store, keypair256, keypair512):
    """Out-of-range ciphertexts, bits above the slots, a slot above its footprint's largest sum and a
    non-zero layer past the volume's end are refused before any pixel; another key is refused."""
    pub, priv = keypair256
    img = slice_(store, hevr.Plane.coronal(store, 3), "trilinear")
    assert img.decrypt(priv).shape == img.shape
    S, K = store.packing.slots, store.packing.slot_bits
    zero = np.zeros(pub.ciphertext_bytes, np.uint8)
    with pytest.raises(IntegrityError, match=r"not in \(0, n²\)"):
        _tampered(img, 0, zero).decrypt(priv)
    with pytest.raises(IntegrityError, match="bits set above its 4 slots"):
        _tampered(img, 0, _record(pub, 1 << (S * K))).decrypt(priv)
    with pytest.raises(IntegrityError, match="above the largest sum"):
        _tampered(img, 0, _record(pub, (1 << K) - 1)).decrypt(priv)
    last = int(img.plan.starts[1]) - 1  # footprint 0's last pack: layers 12..15 of 13
    assert img.plan.value_layers()[1][last] == 12
    with pytest.raises(IntegrityError, match="above the largest sum"):
        _tampered(img, last, _record(pub, 1 << (2 * K))).decrypt(priv)  # layer 14 does not exist
    with pytest.raises(IntegrityError, match="tiles"):
        PackedSlice(
            plan=img.plan,
            plane=img.plane,
            fingerprint=img.fingerprint,
            n=img.n,
            exponent=img.exponent,
            offset=img.offset,
            span=img.span,
            ciphertexts=[],
            store_id=img.store_id,
        ).decrypt(priv)
    with pytest.raises(KeyMismatchError):
        img.decrypt(keypair512[1])


def test_resident_and_distributed(store, keypair256, cluster):
    """Streamed, resident and on a distributed cluster: the same ciphertexts and pixels."""
    plane = hevr.Plane.sagittal(store, 4.6)
    base = slice_(store, plane, "trilinear")
    with dask.config.set(scheduler="sync"):
        res = store.persist()
        again = slice_(res, plane, "trilinear")
    assert again.stats["resident"] and not base.stats["resident"]
    far = slice_(store, plane, "trilinear", client=cluster)
    for other in (again, far):
        assert all((a == b).all() for a, b in zip(base.ciphertexts, other.ciphertexts))
    assert np.array_equal(far.decrypt(keypair256[1]), base.decrypt(keypair256[1]))


def test_plan_is_public_and_bricks_partition(store):
    """The plan needs no key; every product of every brick lands in exactly one output value, and the
    bricks' pairs together cover every footprint voxel of every pack the plan computes."""
    plane = hevr.Plane.oblique(store, normal=(1, 1, 0), width=15, height=17)
    plan = PlanePlan.build(plane, SHAPE, SPACING, (4, 4, 4), store.packing, "trilinear")
    total = sum(len(plan.brick_pairs(idx)[0]) for idx in np.ndindex(store.grid))
    per_fp = np.bincount(plan.fp_id, minlength=plan.n_footprints)
    assert total == int((per_fp * (plan.packs[:, 1] - plan.packs[:, 0])).sum())
    assert plan.fp_w.min() > 0 and plan.term_alpha.min() > 0
