"""Verified renders (hevr/rendering/verify.py) on verifiable stores (encrypt_volume(verifiable=True)).

Honest renders always pass (cameras × modes × samplings, slices, resident bricks); each attack of
issue 28 is caught with a VerificationError — and the same attack without verification gives a
plausible image, so the check is what catches it: another camera's image; swapped bricks with
recomputed digests; E(δ) multiplied into one pixel; tags taken from another store of the same key;
a replayed older frame of the same view after the data changed; a store re-encrypted by the server
from guessed values."""

from __future__ import annotations

import dataclasses
import logging
import shutil

import dask
import numpy as np
import pytest
import zarr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hevr
from hevr.backends import CpuBackend
from hevr.cli.main import main
from hevr.crypto.tags import betas, tag_key_of
from hevr.image.stamp import Stamp
from hevr.rendering import verify as verify_module
from hevr.store.digests import brick_digest, marker
from hevr.store.metadata import VolumeMetadata, metadata_checksum

CPU = CpuBackend()
NODES = [(0.3, "red"), (0.8, "blue")]
VOL = np.random.default_rng(3).integers(0, 256, (10, 9, 8)).astype(np.uint8)


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256):
    """A verifiable store (scalar + 3-dim vector), and an unverifiable one of the same volume."""
    folder = tmp_path_factory.mktemp("verify")
    _, priv = keypair256
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(VOL, folder / "v.zarr", priv, brick=4, vector_dims=3, progress=False, verifiable=True)
        plain = hevr.encrypt_volume(VOL, folder / "p.zarr", priv, brick=4, progress=False)
    return ev, plain


def _render(ev, cam=None, *args, **kw):
    cam = cam or hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=12, height=10)
    with dask.config.set(scheduler="sync"):
        return hevr.render(ev, cam, *args, progress=False, cache=False, **kw)


def _copy(ev, tmp_path, name="c.zarr"):
    shutil.copytree(ev.path, tmp_path / name)
    return hevr.open_volume(tmp_path / name)


def _rewrite(ev, index, channel, records):
    """Write a brick's records and recompute its digest marker, as a server with write access would."""
    group = zarr.open_group(ev.path, mode="r+")
    sl = ev.brick_slices(index)
    group[channel][sl if channel.startswith("scalar") else (slice(None),) + sl] = records
    digests = [
        brick_digest(ev.meta.store_id, ch, index, ev.read_brick_bytes(index, ch, verify=False))
        for ch in ev.meta.channel_names
    ]
    group["done"][index] = marker(digests)


def _rewrite_level(view, index, channel, records):
    """_rewrite for a pyramid level's view (its arrays under levels/L/)."""
    group = zarr.open_group(view.path, mode="r+")
    sl = view.brick_slices(index)
    group[view.prefix + channel][sl if channel.startswith("scalar") else (slice(None),) + sl] = records
    digests = [
        brick_digest(view.meta.store_id, view.prefix + ch, index, view.read_brick_bytes(index, ch, verify=False))
        for ch in view.meta.channel_names
    ]
    group[view.prefix + "done"][index] = marker(digests)


def test_a_verifiable_store_holds_a_tag_channel_per_channel(stores, keypair256):
    ev, plain = stores
    pub, priv = keypair256
    assert ev.meta.tags and not plain.meta.tags
    assert ev.meta.channel_names == ("scalar", "vector", "scalar_tag", "vector_tag")
    assert ev.meta.components("vector_tag") == 3
    meta = VolumeMetadata.from_dict(ev.meta.to_dict())
    assert meta.tags and "tags" not in plain.meta.to_dict()
    ev.verify()  # every digest, the tags' included
    key, n = tag_key_of(priv), int(pub.n)
    tags = CPU.decrypt(priv, ev.read_brick((0, 0, 0), "scalar_tag"))
    data = CPU.decrypt(priv, ev.read_brick((0, 0, 0), "scalar"))
    vox = np.ravel_multi_index(np.meshgrid(*(np.arange(4),) * 3, indexing="ij"), VOL.shape).reshape(-1)
    beta = [
        int.from_bytes(b.astype("<u4").tobytes(), "little") for b in betas(key, ev.meta.store_id, "scalar", 0, 0, vox)
    ]
    assert [t % n for t in tags] == [(key.alpha * m + b) % n for m, b in zip(data, beta)]


def test_verifiable_stores_on_object_storage_and_in_memory(keypair256):
    """memory:// (the object-store layout checks): vector tag chunks are found; persisting keeps
    the data channels only (the tags are always streamed)."""
    _, priv = keypair256
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(
            VOL, "memory://hevr-verify/v.zarr", priv, brick=4, vector_dims=2, progress=False, verifiable=True
        )
        ev = hevr.open_volume("memory://hevr-verify/v.zarr")
        assert ev.meta.channel_names == ("scalar", "vector", "scalar_tag", "vector_tag")
        resident = ev.persist()
        assert resident.resident.channels == ("scalar", "vector")
        img = hevr.render(
            resident,
            hevr.Camera.orbit(ev, azimuth=20, width=8, height=8),
            "tf",
            nodes=NODES,
            progress=False,
            cache=False,
        )
    img.decrypt(priv)


def test_the_tags_field_is_validated(stores):
    ev, _ = stores
    d = ev.meta.to_dict()
    d["tags"] = "yes"
    d["checksum"] = metadata_checksum(d)
    with pytest.raises(hevr.CorruptStoreError, match="tags"):
        VolumeMetadata.from_dict(d)


def test_verifiable_needs_the_private_key_and_a_bool(tmp_path, keypair256):
    pub, priv = keypair256
    with pytest.raises(hevr.ParameterError, match="verifiable: expected a PrivateKey"):
        hevr.encrypt_volume(VOL, tmp_path / "x.zarr", pub, brick=4, progress=False, verifiable=True)
    with pytest.raises(hevr.ParameterError, match="verifiable: expected True, False or None"):
        hevr.encrypt_volume(VOL, tmp_path / "x.zarr", priv, brick=4, progress=False, verifiable="yes")
    assert not (tmp_path / "x.zarr").exists()


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    azimuth=st.floats(-180, 180),
    elevation=st.floats(-80, 80),
    case=st.sampled_from(
        [
            ("xray", "nearest", {}),
            ("xray", "trilinear", {}),
            ("tf", "nearest", {"nodes": NODES}),
            ("emphasize", "trilinear", {"density": 0.5}),
        ]
    ),
)
def test_honest_renders_always_verify(stores, keypair256, azimuth, elevation, case):
    ev, _ = stores
    _, priv = keypair256
    mode, sampling, kw = case
    cam = hevr.Camera.orbit(ev, azimuth=azimuth, elevation=elevation, width=11, height=9)
    img = _render(ev, cam, mode, sampling, **kw)
    assert img.verification is not None and img.stats["verify_s"] >= 0
    got = img.decrypt(priv)
    assert np.all(
        np.abs(got - hevr.render_plain(VOL, cam, mode, sampling, vector_dims=3, **kw))
        <= hevr.error_bound(ev, cam, mode, sampling, **kw)
    )


def test_trilinear_weights_beyond_2_31_verify(stores, keypair256):
    """Many weight digits and a short step: per-pair weights pass 2^31 (the client splits them)."""
    ev, _ = stores
    _, priv = keypair256
    img = _render(
        ev, hevr.Camera.orbit(ev, azimuth=25, elevation=15, width=6, height=5), "xray", "trilinear", step=0.25, digits=9
    )
    img.decrypt(priv)


def test_slices_and_resident_bricks_verify(stores, keypair256):
    ev, _ = stores
    _, priv = keypair256
    with dask.config.set(scheduler="sync"):
        plane = hevr.Plane.axial(ev, 4, width=9, height=10)
        img = hevr.render_slice(ev, plane, progress=False)
        assert img.verification is not None
        img.decrypt(priv)
        resident = ev.persist("scalar")
    img = _render(resident)
    assert img.stats["resident"] and img.verification is not None
    img.decrypt(priv)


def test_a_pinned_store_id_refuses_any_other_store(stores, keypair256, tmp_path):
    """A server holding another verifiable store of the same key (or one without tags) cannot
    answer with it when the owner pins the id encrypt_volume returned."""
    ev, plain = stores
    _, priv = keypair256
    _render(ev, verify=ev.meta.store_id).decrypt(priv)
    with dask.config.set(scheduler="sync"):
        other = hevr.encrypt_volume(255 - VOL, tmp_path / "o.zarr", priv, brick=4, progress=False, verifiable=True)
    _render(other).decrypt(priv)  # a valid verified render, of the other store
    for served in (other, plain):
        with pytest.raises(hevr.VerificationError, match=f"expected the store {ev.meta.store_id}"):
            _render(served, verify=ev.meta.store_id)
    with pytest.raises(hevr.ParameterError, match="a store id of 16 lower-case hex digits"):
        _render(ev, verify="not-an-id")
    assert _render(ev, verify=np.False_).verification is None


def test_what_cannot_be_verified_is_said(stores, caplog):
    ev, plain = stores
    with pytest.raises(
        hevr.ParameterError, match="verify: expected a request that can be verified, got the store has no tags"
    ):
        _render(plain, verify=True)
    with pytest.raises(hevr.ParameterError, match="finish='server'"):
        _render(ev, finish="server", verify=True)
    with pytest.raises(hevr.ParameterError, match="verify: expected True, False, None or a store id"):
        _render(ev, verify=3)
    verify_module._WARNED.clear()
    with caplog.at_level(logging.WARNING, logger="hevr.rendering.verify"):
        img = _render(ev, finish="server")
        _render(ev, finish="server")
    assert img.verification is None and caplog.text.count("not verified: finish='server'") == 1  # once a store
    assert _render(ev, verify=False).verification is None
    assert _render(plain).verification is None


# -- the attacks ------------------------------------------------------------------------------------
def test_another_camera_s_image_is_caught(stores, keypair256):
    ev, _ = stores
    _, priv = keypair256
    asked = _render(ev, hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=12, height=10))
    other = _render(ev, hevr.Camera.orbit(ev, azimuth=34, elevation=20, width=12, height=10))
    forged = dataclasses.replace(other, verification=asked.verification)
    dataclasses.replace(forged, verification=None).decrypt(priv)  # a plausible image without the check
    with pytest.raises(hevr.VerificationError, match="not those of the verified view"):
        forged.decrypt(priv)  # its public fields give it away first
    # the other view's ray sums under the asked view's public fields (as many hit pixels): the tags catch it
    # parallel views down z, shifted in x: every ray crosses the whole depth, so the sample counts agree
    cam2, cam3 = (
        hevr.Camera(
            (x, 4.0, 30.0), (x, 4.0, 4.5), view_up=(0, 1, 0), width=12, height=10, parallel=True, parallel_scale=2.0
        )
        for x in (3.5, 3.0)
    )
    a, b = _render(ev, cam2), _render(ev, cam3)
    assert a.hits.all() and np.array_equal(a.samples, b.samples)
    swapped = dataclasses.replace(a, ciphertexts=b.ciphertexts)
    assert not np.array_equal(dataclasses.replace(swapped, verification=None).decrypt(priv), a.decrypt(priv))
    with pytest.raises(hevr.VerificationError, match="does not verify"):
        swapped.decrypt(priv)


def test_swapped_bricks_with_recomputed_digests_are_caught(stores, keypair256, tmp_path):
    ev, _ = stores
    _, priv = keypair256
    bad = _copy(ev, tmp_path)
    a, b = (0, 0, 0), (1, 0, 0)  # two full 4³ bricks
    for ch in ("scalar", "scalar_tag"):  # data and tags moved together, digests recomputed
        da, db = bad.read_brick_bytes(a, ch), bad.read_brick_bytes(b, ch)
        _rewrite(bad, a, ch, db)
        _rewrite(bad, b, ch, da)
    bad = hevr.open_volume(bad.path)
    bad.verify()  # every accident check passes
    wrong = _render(bad, verify=False).decrypt(priv)  # a plausible, wrong image
    assert not np.array_equal(wrong, _render(ev).decrypt(priv))
    with pytest.raises(hevr.VerificationError):
        _render(bad).decrypt(priv)


def test_e_delta_added_to_one_pixel_is_caught(stores, keypair256):
    ev, _ = stores
    pub, priv = keypair256
    img = _render(ev)
    t = next(i for i, c in enumerate(img.ciphertexts) if len(c))
    recs = img.ciphertexts[t].copy()
    n2 = int(pub.nsquare)
    c = int.from_bytes(recs[0].tobytes(), "big") * int(pub.encrypt(1)) % n2  # +1 to the group's first value
    recs[0] = np.frombuffer(c.to_bytes(recs.shape[1], "big"), np.uint8)
    forged = dataclasses.replace(img, ciphertexts=[recs if i == t else x for i, x in enumerate(img.ciphertexts)])
    dataclasses.replace(forged, verification=None).decrypt(priv)  # passes every range check
    with pytest.raises(hevr.VerificationError):
        forged.decrypt(priv)


def test_tags_from_another_store_of_the_same_key_are_caught(stores, keypair256, tmp_path):
    """Another store's data with its own (valid) tags, passed off under this store's id."""
    ev, _ = stores
    _, priv = keypair256
    with dask.config.set(scheduler="sync"):
        twin = hevr.encrypt_volume(
            255 - VOL, tmp_path / "twin.zarr", priv, brick=4, vector_dims=3, progress=False, verifiable=True
        )
    _render(twin).decrypt(priv)  # in its own store, it verifies
    bad = _copy(ev, tmp_path)
    for index in bad.brick_indices():
        for ch in ("scalar", "scalar_tag"):
            _rewrite(bad, index, ch, twin.read_brick_bytes(index, ch))
    with pytest.raises(hevr.VerificationError):
        _render(hevr.open_volume(bad.path)).decrypt(priv)


def test_a_replayed_older_frame_is_caught(keypair256, tmp_path):
    _, priv = keypair256
    path = tmp_path / "r.zarr"
    with dask.config.set(scheduler="sync"):
        old = hevr.encrypt_volume(VOL, path, priv, brick=4, progress=False, verifiable=True)
        before = _render(old)
        new = hevr.encrypt_volume(255 - VOL, path, priv, brick=4, progress=False, verifiable=True, overwrite=True)
    now = _render(new)
    replayed = dataclasses.replace(now, ciphertexts=before.ciphertexts)  # the old frame, today's aggregate
    with pytest.raises(hevr.VerificationError):
        replayed.decrypt(priv)
    now.decrypt(priv)


def test_a_store_re_encrypted_from_guessed_values_is_caught(stores, keypair256, tmp_path):
    ev, _ = stores
    pub, priv = keypair256
    bad = _copy(ev, tmp_path)
    width = ev.meta.ciphertext_bytes
    for index in bad.brick_indices():  # the server's guess: a constant volume, encrypted with the public key
        shape = tuple(s.stop - s.start for s in bad.brick_slices(index))
        guess = CPU.to_bytes([pub.encrypt(100) for _ in range(int(np.prod(shape)))], width).reshape(shape + (width,))
        _rewrite(bad, index, "scalar", guess)
        _rewrite(bad, index, "scalar_tag", guess)  # and tags it can make: encryptions of its guesses
    with pytest.raises(hevr.VerificationError):
        _render(hevr.open_volume(bad.path)).decrypt(priv)


def test_a_verified_render_on_a_cluster(stores, keypair256, cluster):
    """The tag map and the aggregates run on the workers; the client gets one record per tile."""
    ev, _ = stores
    _, priv = keypair256
    cam = hevr.Camera.orbit(ev, azimuth=10, elevation=30, width=12, height=10)
    img = hevr.render(ev, cam, "tf", "trilinear", nodes=NODES, client=cluster, progress=False, cache=False)
    assert img.verification is not None
    img.decrypt(priv)
    resident = ev.persist("vector", client=cluster)
    resident.resident.wait()
    img = hevr.render(resident, cam, "tf", "nearest", nodes=NODES, client=cluster, progress=False, cache=False)
    assert img.stats["resident"]
    img.decrypt(priv)


def test_pyramid_levels_of_a_verifiable_store_verify(stores, keypair256, tmp_path):
    """The pyramid builds the tags' levels as the values' (125 ⊗ the product of 8 children), and the
    client's β follow (level_betas); a level's swapped bricks are caught."""
    ev, _ = stores
    _, priv = keypair256
    with dask.config.set(scheduler="sync"):
        built = hevr.build_pyramid(_copy(ev, tmp_path), 2, progress=False)
    assert built.levels == 2 and "scalar_tag" in built.meta.levels[0].arrays
    built.at_level(1).verify()
    for level in (1, 2):
        for mode, sampling, kw in (("xray", "trilinear", {}), ("tf", "nearest", {"nodes": NODES})):
            img = _render(built, None, mode, sampling, level=level, **kw)
            assert img.verification is not None and img.verification.level == level
            img.decrypt(priv)
    view = built.at_level(1)
    for ch in ("scalar", "scalar_tag"):  # a level brick's voxels moved (with their tags), digests recomputed
        _rewrite_level(view, (0, 0, 0), ch, view.read_brick_bytes((0, 0, 0), ch)[::-1].copy())
    with pytest.raises(hevr.VerificationError):
        _render(hevr.open_volume(built.path), level=1).decrypt(priv)
    _render(built).decrypt(priv)  # level 0 untouched


def test_a_frame_file_carries_its_verification(stores, keypair256, tmp_path, caplog):
    """Saved with the key, the record travels with the key holder's stamp and the check runs again
    on loading; without the key the record is left out (said in a warning); a file whose
    ciphertexts were swapped for another view's (its SHA-256 recomputed) is caught by the stamp; a
    frame that does not verify is refused before it is stamped; a damaged record is named."""
    ev, _ = stores
    _, priv = keypair256
    img = _render(ev)
    img.save(tmp_path / "f.hevr", private_key=priv)
    back = hevr.load_image(tmp_path / "f.hevr")
    assert back.verification is not None and back.verification.to_dict() == img.verification.to_dict()
    assert back.stamp is not None and not back.verification.drawn_here
    np.testing.assert_array_equal(back.decrypt(priv, require_verified=ev.meta.store_id), img.decrypt(priv))
    with caplog.at_level(logging.WARNING):
        img.save(tmp_path / "nokey.hevr")
    assert "its verification record is left out" in caplog.text
    assert hevr.load_image(tmp_path / "nokey.hevr").verification is None
    with pytest.raises(hevr.VerificationError, match="not verified"):
        hevr.load_image(tmp_path / "nokey.hevr").decrypt(priv, require_verified=True)
    other = _render(ev, hevr.Camera.orbit(ev, azimuth=34, elevation=20, width=12, height=10))
    dataclasses.replace(back, ciphertexts=other.ciphertexts, hits=other.hits, samples=other.samples).save(
        tmp_path / "forged.hevr"
    )
    with pytest.raises(hevr.VerificationError, match="stamp that does not match"):
        hevr.load_image(tmp_path / "forged.hevr").decrypt(priv)
    with pytest.raises(hevr.VerificationError, match="sample counts"):  # means halved, tags untouched
        dataclasses.replace(img, samples=img.samples * 2).save(tmp_path / "scaled.hevr", private_key=priv)
    assert not (tmp_path / "scaled.hevr").exists()
    bad = dataclasses.replace(img.verification, seed=b"short", drawn_here=False)
    dataclasses.replace(img, verification=bad, stamp=Stamp("hmac-sha256:" + "0" * 64, b"", "bad.hevr")).save(
        tmp_path / "bad.hevr"
    )
    with pytest.raises(hevr.IntegrityError, match="'verification.seed': expected 64 lower-case hex digits"):
        hevr.load_image(tmp_path / "bad.hevr")
    assert _render(ev, verify=False).verification is None


def test_the_command_line_verifies(tmp_path, capsys):
    def run(*argv):
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err

    key = tmp_path / "key.json"
    assert main(["keygen", "--bits", "256", "--out", str(key), "-q"]) == 0
    code, out, err = run(
        "encrypt", "phantom:8", "--key", key, "--out", tmp_path / "v.zarr", "--brick", "4", "--verifiable"
    )
    assert code == 0 and "verifiable: store id" in out, err
    assert hevr.open_volume(tmp_path / "v.zarr").meta.tags
    code, _, err = run("render", tmp_path / "v.zarr", "--out", tmp_path / "n.hevr", "--size", "8x8", "-q")
    assert code == 0 and "not verified: no --key" in err, err  # the cluster's process draws no seed
    assert hevr.load_image(tmp_path / "n.hevr").verification is None
    code, _, err = run("decrypt", tmp_path / "n.hevr", "--key", key, "--out", tmp_path / "n.png", "--require-verified")
    assert code == 1 and "not verified" in err and not (tmp_path / "n.png").exists(), err
    code, out, err = run("render", tmp_path / "v.zarr", "--out", tmp_path / "f.hevr", "--size", "8x8", "--key", key)
    sid = hevr.open_volume(tmp_path / "v.zarr").meta.store_id
    assert code == 0 and f"verified: the frame is the render of store {sid}" in out, err
    code, out, err = run(
        "decrypt", tmp_path / "f.hevr", "--key", key, "--out", tmp_path / "f.png", "--require-verified", sid
    )
    assert code == 0 and f"verified: the frame is the render of store {sid}" in out and "level 0" in out, err
    code, out, err = run(
        "decrypt", tmp_path / "f.hevr", "--key", key, "--out", tmp_path / "g.png", "--require-verified", "0" * 16
    )
    assert code == 1 and "expected a frame of the store 0000000000000000" in err, err
    code, _, err = run(
        "render", tmp_path / "v.zarr", "--out", tmp_path / "u.hevr", "--size", "8x8", "--no-verify", "--key", key, "-q"
    )
    assert code == 0 and hevr.load_image(tmp_path / "u.hevr").verification is None, err
    code, out, err = run("decrypt", tmp_path / "u.hevr", "--key", key, "--out", tmp_path / "u.png")
    assert code == 0 and "not verified" in out, err  # a store with tags: the key's policy lets it say so
    code, _, err = run(
        "render",
        tmp_path / "v.zarr",
        "--out",
        tmp_path / "p.hevr",
        "--size",
        "8x8",
        "--verify",
        sid,
        "--key",
        key,
        "-q",
    )
    assert code == 0 and hevr.load_image(tmp_path / "p.hevr").verification.store_id == sid, err
    code, _, err = run(
        "render",
        tmp_path / "v.zarr",
        "--out",
        tmp_path / "q.hevr",
        "--size",
        "8x8",
        "--verify",
        "0" * 16,
        "--key",
        key,
        "-q",
    )
    assert code != 0 and "expected the store 0000000000000000" in err, err
    code, _, err = run("render", tmp_path / "v.zarr", "--out", tmp_path / "q.hevr", "--size", "8x8", "--verify", sid)
    assert code == 2 and "--verify: expected --key KEY.json as well" in err, err
    code, _, err = run("render", "--verify", tmp_path / "v.zarr", "--out", tmp_path / "r.hevr")
    assert code == 2 and "--verify: expected a store id of 16 lower-case hex digits" in err, err
    code, _, err = run(
        "encrypt", "phantom:8", "--key", tmp_path / "key.pub.json", "--out", tmp_path / "p.zarr", "--verifiable", "-q"
    )
    assert code == 2 and err.startswith("hevr: error: --verifiable: expected a PrivateKey"), err


def test_verified_renders_on_the_kernel_backend(stores, keypair256):
    """The tag map and the aggregates through another backend's interface (cuda-host: the GPU
    backend's kernels on the CPU) give the same check."""
    ev, _ = stores
    _, priv = keypair256
    for mode, kw in (("xray", {}), ("tf", {"nodes": NODES})):
        img = _render(ev, None, mode, "trilinear", backend="cuda-host", **kw)
        assert img.stats["backend"] == "cuda-host" and img.verification is not None
        img.decrypt(priv)
