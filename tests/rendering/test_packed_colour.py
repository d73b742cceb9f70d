"""Transfer-function and emphasis frames of packed stores (hevr.rendering.packed.colour): the vector
channel packed with the scalar's slots, exact component sums, the slice reference within
error_bound, the per-voxel client colouring, refusals, integrity and the stored tags."""

from __future__ import annotations

import dataclasses
import logging

import dask
import numpy as np
import pytest

import hevr
from hevr.colour import Colouring, colour
from hevr.crypto.tags import betas, raw_tags, tag_key_of
from hevr.errors import CorruptStoreError, IntegrityError, ParameterError, VerificationError
from hevr.image import image_from_bytes
from hevr.rendering.packed.colour import PackedColourImage
from hevr.store.metadata import VolumeMetadata
from hevr.store.packing import slot_bits, unpack_slots
from hevr.volume.density import encode_density, normalize_density

SHAPE = (13, 9, 11)  # z (packing axis) not a multiple of the slots
SPACING = (1.0, 0.8, 1.3)
K = 3  # vector_dims
NODES = [(0.15, "red"), (0.5, "lime"), (0.85, "#3050ff")]
VIEWS = [(90, 0), (60, 10), (250, 30)]  # around z, and leaning towards it (classes > 1)


def cam(ev, az, el, w=12, h=10):
    return hevr.Camera.orbit(ev, azimuth=az, elevation=el, width=w, height=h, parallel=True)


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-colour") / "c.zarr"
    return hevr.encrypt_volume(
        volume, path, keypair256[1], brick=4, spacing=SPACING, layout="packed", vector_dims=K, progress=False
    )


def components(volume, store):
    """The stored mantissas of e(d)'s components (k, z, y, x), as the owner quantised them."""
    enc = encode_density(normalize_density(volume, store.value_range), K)
    return np.moveaxis(np.rint(enc * 10.0**store.meta.vector.digits).astype(np.int64), -1, 0)


def render(ev, camera, sampling, **kw):
    kw.setdefault("progress", False)
    kw.setdefault("verify", False)
    return hevr.render(ev, camera, sampling=sampling, **kw)


def test_store_layout_and_tags(store, keypair256, volume):
    """The vector array holds k packed components per pack, with the scalar's S and K (K sized for
    10^digits), one tag per packed ciphertext and component with β of (vector, component j)."""
    priv = keypair256[1]
    info = store.packing
    assert store.meta.channel_names == ("scalar", "vector", "scalar_tag", "vector_tag")
    assert info.slot_bits == slot_bits(1000, info.weight_bits, max(SHAPE[1:])) and info.slots == 4
    q = components(volume, store)
    idx = (3, 2, 1)  # the ragged last pack along z: slots beyond the volume hold 0
    batches = store.read_brick(idx, "vector")
    tags = store.read_brick(idx, "vector_tag")
    assert len(batches) == len(tags) == K
    sl = tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(idx, store.brick, SHAPE))
    tk = tag_key_of(priv)
    packed_shape = info.array_shape(SHAPE)
    pz, py, px = np.meshgrid(
        *(
            np.arange(s.start // (info.slots if a == 0 else 1), -(-s.stop // (info.slots if a == 0 else 1)))
            for a, s in enumerate(sl)
        ),
        indexing="ij",
    )
    packs = np.ravel_multi_index((pz, py, px), packed_shape).reshape(-1)
    for j in range(K):
        plain = [int(priv.raw_decrypt(c)) for c in batches[j]]
        slots = unpack_slots(plain, info.slots, info.slot_bits).reshape(
            1, sl[1].stop - sl[1].start, sl[2].stop - sl[2].start, info.slots
        )
        got = np.moveaxis(slots, -1, 1).reshape(info.slots, *slots.shape[1:3])
        want = q[j][sl]
        assert (got[: want.shape[0]] == want).all() and not got[want.shape[0] :].any()
        t = [int(priv.raw_decrypt(c)) for c in tags[j]]
        assert t == raw_tags(tk, [p % tk.n for p in plain], betas(tk, store.meta.store_id, "vector", 0, j, packs))
        assert t != raw_tags(
            tk, [p % tk.n for p in plain], betas(tk, store.meta.store_id, "vector", 0, 0 if j else 1, packs)
        )


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("view", VIEWS)
def test_tf_exact_sums_and_reference(store, keypair256, volume, view, sampling):
    """Each component's decrypted sums are the plan's exact plain sums of its mantissas, and the
    coloured frame lies within error_bound of render_plain(..., mode='tf', slices=True)."""
    priv = keypair256[1]
    c = cam(store, *view)
    img = render(store, c, sampling, mode="tf", nodes=NODES)
    assert isinstance(img, PackedColourImage) and img.shape == (10, 12) and not img.verified
    q = components(volume, store)
    sums = img.decrypt_sums(priv)
    assert sums.shape == (K,) + img.plan.geometry.size
    for j in range(K):
        assert (sums[j] == img.plan.plain_sums(q[j])).all()
    arr = img.decrypt(priv)
    ref = hevr.render_plain(
        volume,
        c,
        mode="tf",
        nodes=NODES,
        sampling=sampling,
        spacing=SPACING,
        vector_dims=K,
        value_range=store.value_range,
        slices=True,
    )
    bound = hevr.error_bound(store, c, mode="tf", nodes=NODES, sampling=sampling)
    assert arr.shape == ref.shape == bound.shape == (10, 12, 3)
    assert (np.abs(arr - ref) <= bound).all()
    assert ref.max() > 0.05 and bound.max() < 0.01  # the view sees the volume; the bound is not vacuous
    assert img.stats["components"] == K and img.stats["ops"]["pairs"] > 0
    if view != (90, 0):
        assert img.plan.classes > 1 and img.stats["ops"]["combine"] > 0


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_emphasis_and_recolouring(store, keypair256, volume, sampling):
    """Emphasis within its bound; the frame's means re-coloured as a per-voxel client frame is
    (hevr.colour.colour), the scalar X-ray of the same store unchanged."""
    priv = keypair256[1]
    c = cam(store, 60, 10)
    img = render(store, c, sampling, mode="emphasize", density=0.4)
    arr = img.decrypt(priv)
    ref = hevr.render_plain(
        volume,
        c,
        mode="emphasize",
        density=0.4,
        sampling=sampling,
        spacing=SPACING,
        vector_dims=K,
        value_range=store.value_range,
        slices=True,
    )
    bound = hevr.error_bound(store, c, mode="emphasize", density=0.4, sampling=sampling)
    assert arr.shape == ref.shape == bound.shape == (10, 12)
    assert (np.abs(arr - ref) <= bound).all() and ref.max() > 0.1
    frame = img.decrypt_frame(priv)
    assert frame.means.shape == (10, 12, K) and frame.channel == "vector"
    assert np.array_equal(frame.image, arr)
    tf = frame.recolour(nodes=NODES)  # another colouring, no second render
    assert np.array_equal(tf, colour(frame.means, Colouring("tf", nodes=NODES)))
    assert np.array_equal(img.decrypt(priv, nodes=NODES), tf)
    ref_tf = hevr.render_plain(
        volume,
        c,
        mode="tf",
        nodes=NODES,
        sampling=sampling,
        spacing=SPACING,
        vector_dims=K,
        value_range=store.value_range,
        slices=True,
    )
    assert (np.abs(tf - ref_tf) <= hevr.error_bound(store, c, mode="tf", nodes=NODES, sampling=sampling)).all()
    xray = render(store, c, sampling)  # the scalar channel of the same store
    xref = hevr.render_plain(volume, c, sampling=sampling, spacing=SPACING, slices=True)
    assert (np.abs(xray.decrypt(priv) - xref) <= hevr.error_bound(store, c, sampling=sampling)).all()


def test_colouring_stays_in_process(store):
    import pickle

    img = render(store, cam(store, 90, 0), "nearest", mode="tf", nodes=NODES)
    assert img.colouring is not None
    again = pickle.loads(pickle.dumps(img))
    assert again.colouring is None and "red" not in repr(img) and "0.15" not in repr(img)


def test_refusals(store, keypair256, tmp_path, volume):
    """Refused before any work with the option named."""
    c = cam(store, 90, 0)
    with pytest.raises(ParameterError, match="nodes: expected a list"):
        render(store, c, "nearest", mode="tf")
    with pytest.raises(ParameterError, match="density: expected a density"):
        render(store, c, "nearest", mode="emphasize")
    with pytest.raises(ParameterError, match="mode: expected one of"):
        render(store, c, "nearest", mode="mip", nodes=NODES)
    with pytest.raises(ParameterError, match="density/nodes: expected None for an X-ray"):
        render(store, c, "nearest", nodes=NODES)
    with pytest.raises(ParameterError, match="camera: expected a parallel camera"):
        render(store, hevr.Camera.orbit(store, azimuth=90), "nearest", mode="tf", nodes=NODES)
    with pytest.raises(ParameterError, match="principal axis is not the packing axis"):
        render(store, cam(store, 0, 0), "nearest", mode="tf", nodes=NODES)
    with pytest.raises(ParameterError, match="gradient: expected False"):
        render(store, c, "nearest", mode="tf", nodes=NODES, gradient=True)
    with pytest.raises(VerificationError, match="expected the store 0123456789abcdef"):
        render(store, c, "nearest", mode="tf", nodes=NODES, verify="0123456789abcdef")
    with pytest.raises(ParameterError, match="step: expected 1.0"):
        render(store, c, "nearest", mode="tf", nodes=NODES, step=0.5)
    with pytest.raises(ParameterError, match="finish: expected 'client'"):
        render(store, c, "nearest", mode="tf", nodes=NODES, finish="server")
    with pytest.raises(ParameterError, match="mode: expected an X-ray"):
        hevr.error_bound(store, c, mode="tf", nodes=NODES, gradient=True)
    with pytest.raises(ParameterError, match="slices: expected mode='xray', step=1 and gradient=False"):
        hevr.render_plain(volume, c, gradient=True, slices=True)  # an X-ray has no gradient modulation
    with pytest.raises(ParameterError, match="level: expected 0"):
        hevr.render_plain(volume, c, mode="tf", nodes=NODES, level=1, slices=True)
    img = render(store, c, "nearest", mode="tf", nodes=NODES)
    with pytest.raises(VerificationError, match="not verified"):
        img.decrypt(keypair256[1], require_verified=True)  # rendered with verify=False
    priv = keypair256[1]
    with pytest.raises(ParameterError, match="layout: expected 'voxel' for a store without the scalar channel"):
        hevr.encrypt_volume(
            volume, tmp_path / "g.zarr", priv, layout="packed", vector_dims=K, scalar=False, progress=False
        )
    with pytest.raises(ParameterError, match="levels: expected 0 for a packed store with the vector channel"):
        hevr.encrypt_volume(volume, tmp_path / "l.zarr", priv, layout="packed", vector_dims=K, levels=1, progress=False)
    assert not (tmp_path / "g.zarr").exists() and not (tmp_path / "l.zarr").exists()


def test_scalar_only_store_still_refuses_colour(tmp_path, keypair256, volume):
    ev = hevr.encrypt_volume(volume, tmp_path / "s.zarr", keypair256[1], brick=4, layout="packed", progress=False)
    c = cam(ev, 90, 0)
    with pytest.raises(ParameterError, match="mode: expected 'xray' on a packed store without the vector channel"):
        render(ev, c, "nearest", mode="tf", nodes=NODES)
    with pytest.raises(ParameterError, match="mode: expected an X-ray"):
        hevr.error_bound(ev, c, mode="tf", nodes=NODES)


@pytest.mark.parametrize("mode", ["tf", "emphasize"])
def test_verified_by_default(store, keypair256, mode):
    """A verifiable store's colour frame is verified per component (one seed each, drawn after the
    values); it decrypts to the unverified picture, and a changed component or aggregate is caught."""
    import dataclasses

    priv = keypair256[1]
    c = cam(store, 60, 10)
    kw = {"nodes": NODES} if mode == "tf" else {"density": 0.5}
    img = hevr.render(store, c, mode=mode, sampling="trilinear", progress=False, tile=4, **kw)
    assert img.verified and img.verification.components == K and img.verification.channel == "vector"
    arr = img.decrypt(priv, require_verified=store.meta.store_id)
    plain = render(store, c, "trilinear", mode=mode, tile=4, **kw)
    np.testing.assert_array_equal(arr, plain.decrypt(priv))
    comps = list(img.components)
    swapped = [comps[1], comps[0]] + comps[2:]  # two components' values exchanged: each well-formed
    with pytest.raises(VerificationError, match="does not verify"):
        dataclasses.replace(img, components=swapped).decrypt(priv)
    again = hevr.render(store, c, mode=mode, sampling="trilinear", progress=False, tile=4, **kw)
    stale = dataclasses.replace(img.verification, aggregate=again.verification.aggregate)  # another round's
    with pytest.raises(VerificationError, match="does not verify"):
        dataclasses.replace(img, verification=stale).decrypt(priv)


def test_unverified_store_warns(tmp_path, keypair256, volume, caplog):
    ev = hevr.encrypt_volume(
        volume,
        tmp_path / "u.zarr",
        keypair256[1],
        brick=4,
        layout="packed",
        vector_dims=K,
        verifiable=False,
        progress=False,
    )
    with caplog.at_level(logging.WARNING, logger="hevr"):
        img = hevr.render(ev, cam(ev, 90, 0), mode="tf", nodes=NODES, progress=False)
    assert not img.verified and "not verified" in caplog.text


def test_metadata_checks(store):
    """The owner's MAC covers the vector channel; a K edited below the vector span is refused."""
    d = store.meta.to_dict()
    bad = dict(d, layout=dict(d["layout"], slot_bits=slot_bits(255, d["layout"]["weight_bits"], max(SHAPE[1:]))))
    from hevr.store.metadata import metadata_checksum

    bad["checksum"] = metadata_checksum(bad)
    with pytest.raises(CorruptStoreError, match="layout.slot_bits: expected at least"):
        VolumeMetadata.from_dict(bad)
    channels = {k: v for k, v in d["channels"].items() if k != "scalar"}
    arrays = {k: v for k, v in d["arrays"].items() if k not in ("scalar", "scalar_tag")}
    noscalar = dict(d, channels=channels, arrays=arrays)
    noscalar["checksum"] = metadata_checksum(noscalar)
    with pytest.raises(CorruptStoreError, match="channels: expected 'scalar' .and 'vector', 'gradient'. in a packed"):
        VolumeMetadata.from_dict(noscalar)
    levels = dict(d, levels=[{"level": 1}])
    levels["checksum"] = metadata_checksum(levels)
    with pytest.raises(CorruptStoreError, match="levels: expected none in a packed store with the vector channel"):
        VolumeMetadata.from_dict(levels)
    from hevr.store.authenticity import authenticated_fields

    assert authenticated_fields(d)["channels"]["vector"]["dims"] == K


def test_integrity(store, keypair256):
    """A tampered component is refused before any pixel (the X-ray frame's checks, per component)."""
    priv = keypair256[1]
    img = render(store, cam(store, 60, 10), "trilinear", mode="tf", nodes=NODES)
    comp = img.components[1]
    tiles = [t.copy() for t in comp.ciphertexts]
    tiles[0][0, -8:] ^= 0x5A  # a damaged ciphertext: a random plaintext (the integrity margin) or not in (0, n²)
    bad = dataclasses.replace(
        img, components=[img.components[0], dataclasses.replace(comp, ciphertexts=tiles), img.components[2]]
    )
    with pytest.raises(IntegrityError):
        bad.decrypt(priv)
    swapped = dataclasses.replace(img, components=[img.components[1], img.components[0], img.components[2]])
    assert not np.array_equal(swapped.decrypt(priv), img.decrypt(priv))  # each component decodes as its own


def test_resident_and_distributed(store, keypair256, cluster):
    """Streamed, resident (the vector channel persisted) and on a distributed cluster: the same ciphertexts."""
    c = cam(store, 250, 30)
    base = render(store, c, "trilinear", mode="tf", nodes=NODES)
    with dask.config.set(scheduler="sync"):
        res = store.persist(channels="vector")
        again = render(res, c, "trilinear", mode="tf", nodes=NODES)
    assert again.stats["resident"] and not base.stats["resident"]
    far = render(store, c, "trilinear", mode="tf", nodes=NODES, client=cluster)
    for other in (again, far):
        for a, b in zip(base.components, other.components):
            assert all((x == y).all() for x, y in zip(a.ciphertexts, b.ciphertexts))
    assert np.array_equal(far.decrypt(keypair256[1]), base.decrypt(keypair256[1]))


def test_render_frame_recolours_on_the_client(store, keypair256):
    """hevr.render_frame on a packed store with the vector channel: a verified Frame of the k
    components' means that re-colours in numpy, as the per-voxel client frame does."""
    priv = keypair256[1]
    c = cam(store, 60, 10)
    frame = hevr.render_frame(store, c, priv, mode="tf", nodes=NODES, sampling="trilinear", progress=False)
    assert frame.channel == "vector" and frame.components == K and frame.stats["verified"]
    img = render(store, c, "trilinear", mode="tf", nodes=NODES)
    np.testing.assert_allclose(frame.image, img.decrypt(priv), rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        frame.recolour("emphasize", density=0.5), img.decrypt(priv, mode="emphasize", density=0.5), rtol=0, atol=1e-12
    )


@pytest.fixture(scope="module")
def gradient_store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-gradient") / "g.zarr"
    return hevr.encrypt_volume(
        volume,
        path,
        keypair256[1],
        brick=4,
        spacing=SPACING,
        layout="packed",
        vector_dims=K,
        gradient=True,
        progress=False,
    )


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode, kw", [("tf", {"nodes": NODES}), ("emphasize", {"density": 0.5})])
def test_gradient_modulation(gradient_store, keypair256, volume, mode, kw, sampling):
    """gradient=True on a packed store with the gradient channel: g·e(d)'s k components through the
    same plan, verified, within error_bound of render_plain(..., gradient=True, slices=True), and not
    the unmodulated frame; render_frame gives the same picture."""
    priv = keypair256[1]
    ev = gradient_store
    assert ev.meta.channel_names == ("scalar", "vector", "gradient", "scalar_tag", "vector_tag", "gradient_tag")
    c = cam(ev, 60, 10)
    img = hevr.render(ev, c, mode=mode, sampling=sampling, gradient=True, progress=False, tile=4, **kw)
    assert img.channel == "gradient" and img.verified and img.verification.channel == "gradient"
    arr = img.decrypt(priv, require_verified=True)
    ref = hevr.render_plain(
        volume,
        c,
        mode=mode,
        sampling=sampling,
        gradient=True,
        vector_dims=K,
        slices=True,
        value_range=ev.value_range,
        spacing=SPACING,
        **kw,
    )
    assert (np.abs(arr - ref) <= hevr.error_bound(ev, c, mode=mode, sampling=sampling, gradient=True, **kw)).all()
    flat = hevr.render(ev, c, mode=mode, sampling=sampling, progress=False, verify=False, **kw).decrypt(priv)
    assert np.abs(arr - flat).max() > 0.01  # the modulation shows
    frame = hevr.render_frame(ev, c, priv, mode=mode, sampling=sampling, gradient=True, progress=False, **kw)
    assert frame.channel == "gradient" and frame.stats["verified"]
    np.testing.assert_allclose(frame.image, arr, rtol=0, atol=1e-12)


@pytest.mark.parametrize("gradient", [False, True])
def test_colour_frame_files(gradient_store, keypair256, tmp_path, gradient):
    """A packed colour frame as a file: the k components' tiles with the channel, verified only with
    the key holder's stamp and under its name, coloured at decryption; a flipped byte is an error."""
    priv = keypair256[1]
    ev = gradient_store
    c = cam(ev, 60, 10)
    img = hevr.render(ev, c, mode="tf", nodes=NODES, gradient=gradient, sampling="trilinear", tile=4, progress=False)
    want = img.decrypt(priv)
    path = tmp_path / "c.hevr"
    img.save(path, private_key=priv)
    back = hevr.load_image(path)
    assert isinstance(back, PackedColourImage) and back.channel == ("gradient" if gradient else "vector")
    assert back.verified and back.verification.components == K and back.stamp is not None
    np.testing.assert_array_equal(back.decrypt(priv, mode="tf", nodes=NODES, require_verified=True), want)
    np.testing.assert_allclose(
        back.decrypt_frame(priv).recolour("emphasize", density=0.5),
        img.decrypt(priv, mode="emphasize", density=0.5),
        rtol=0,
        atol=1e-12,
    )
    moved = tmp_path / "moved.hevr"
    path.rename(moved)
    with pytest.raises(VerificationError, match="saved this verified frame as"):
        hevr.load_image(moved).decrypt(priv, mode="tf", nodes=NODES, require_verified=True)
    with pytest.warns(hevr.FrameMovedWarning):  # by default: the image, not "verified" for this file
        hevr.load_image(moved).decrypt(priv, mode="tf", nodes=NODES)
    blob = bytearray(img.to_bytes(private_key=priv))
    blob[-40] ^= 1
    with pytest.raises(IntegrityError):
        image_from_bytes(bytes(blob)).decrypt(priv, mode="tf", nodes=NODES)
    bare = tmp_path / "bare.hevr"
    img.save(bare)  # without the key: the record is left out
    assert not hevr.load_image(bare).verified
