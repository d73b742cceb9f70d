"""Pyramid levels of packed stores, encrypted by the owner (hevr.store.packed_levels): the level's
values, its slots, tags and metadata, its frames against the float64 slice reference, resume,
public-key encryption and the refusals."""

from __future__ import annotations

import dataclasses
import json
import logging
import warnings

import numpy as np
import pytest
import zarr

import hevr
import hevr.store.packed_levels as packed_levels
from hevr.crypto.tags import betas, raw_tags, tag_key_of
from hevr.errors import CorruptStoreError, ParameterError
from hevr.store.authenticity import authenticated_fields, metadata_mac
from hevr.store.layout import array_slices
from hevr.store.metadata import VolumeMetadata, metadata_checksum
from hevr.store.packing import unpack_slots
from hevr.volume.pyramid import downsample, level_shape

SHAPE = (13, 9, 11)  # odd sizes: every level repeats an edge voxel
SPACING = (1.0, 0.8, 1.3)
VIEWS = [(90, 10), (60, -15), (250, 30)]


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(46).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair512, volume):
    path = tmp_path_factory.mktemp("packed-levels") / "p.zarr"
    return hevr.encrypt_volume(
        volume,
        path,
        keypair512[1],
        brick=4,
        spacing=SPACING,
        layout="packed",
        levels=2,
        verifiable=True,
        progress=False,
    )


def level_mantissas(view, priv) -> np.ndarray:
    """Every stored mantissa of a (level) view, decrypted and unpacked from its slots: (shape) int."""
    info = view.packing
    out = np.zeros(view.shape, dtype=object)
    for idx in view.brick_indices():
        vals = [int(priv.raw_decrypt(c)) for c in view.read_brick(idx)]
        sl = array_slices(view.meta, idx)
        rec = [s.stop - s.start for s in sl]
        slots = unpack_slots(vals, info.slots, info.slot_bits).reshape(rec + [info.slots])
        cols = np.moveaxis(slots, info.axis, -2)
        cols = cols.reshape(cols.shape[:-2] + (-1,))
        vsl = view.brick_slices(idx)
        block = np.moveaxis(cols[..., : vsl[info.axis].stop - vsl[info.axis].start], -1, info.axis)
        out[vsl] = block.astype(object) + info.offset
    return out


def test_levels_hold_the_pyramid_means(store, keypair512, volume):
    """Every level's packs hold exactly the per-voxel pyramid's mantissas, 125^L·Σ of the 8^L leaves
    = 1000^L·downsample(v, L), at exponent −3L, with slots of their own."""
    priv = keypair512[1]
    assert store.levels == 2 and len(store.meta.levels) == 2
    ev = hevr.open_volume(store.path, verify="full")  # every ciphertext of every level read and checked
    for L in (1, 2):
        view = ev.at_level(L)
        assert view.level == L and view.shape == level_shape(SHAPE, L) and view.layout == "packed"
        assert view.meta.scalar.exponent == -3 * L
        assert view.brick[0] % view.packing.slots == 0 and view.brick[1:] == store.brick[1:]
        want = np.rint(downsample(volume, L) * 1000**L).astype(np.int64)
        assert (level_mantissas(view, priv) == want).all()
    # each level's values carry 3 more digits: wider slots, fewer of them
    slots = [store.packing.slots] + [lv.packing.slots for lv in store.meta.levels]
    bits = [store.packing.slot_bits] + [lv.packing.slot_bits for lv in store.meta.levels]
    assert slots[0] > slots[1] > slots[2] >= 2 and bits[0] < bits[1] < bits[2]
    assert store.written_now["ciphertexts"] == sum(
        int(np.prod(v.packing.array_shape(v.shape))) for v in (ev, ev.at_level(1), ev.at_level(2))
    )


def test_level_tags_use_the_levels_own_betas(store, keypair512):
    """One tag per packed ciphertext of a level: E(α·P + β) with β = betas(..., level, 0, pack index)."""
    priv = keypair512[1]
    key = tag_key_of(priv)
    for L in (1, 2):
        view = store.at_level(L)
        for idx in view.brick_indices():
            data = [int(priv.raw_decrypt(c)) for c in view.read_brick(idx)]
            tags = [int(priv.raw_decrypt(c)) for c in view.read_brick(idx, "scalar_tag")]
            sl = array_slices(view.meta, idx)
            packs = np.ravel_multi_index(
                np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"),
                view.packing.array_shape(view.shape),
            ).reshape(-1)
            assert tags == raw_tags(key, data, betas(key, store.meta.store_id, "scalar", L, 0, packs))
            assert tags != raw_tags(key, data, betas(key, store.meta.store_id, "scalar", 0, 0, packs))


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("level", [1, 2])
def test_level_frames_against_the_reference(store, keypair512, volume, level, sampling):
    """A level's frame: its slot sums are the exact sums of the level's mantissas, and the picture is
    within error_bound(level=) of render_plain(..., slices=True, level=) (the means on the level's grid)."""
    priv = keypair512[1]
    view = store.at_level(level)
    mant = np.rint(downsample(volume, level) * 1000**level).astype(np.int64) - view.packing.offset
    for az, el in VIEWS:
        cam = hevr.Camera.orbit(store, azimuth=az, elevation=el, width=12, height=10, parallel=True)
        img = hevr.render(store, cam, sampling=sampling, level=level, verify=False, progress=False)
        assert (img.decrypt_sums(priv) == img.plan.plain_sums(mant)).all()
        assert img.plan.geometry.size[0] < SHAPE[0]  # the level's rays, not level 0's
        arr = img.decrypt(priv)
        ref = hevr.render_plain(volume, cam, sampling=sampling, spacing=SPACING, slices=True, level=level)
        bound = hevr.error_bound(store, cam, sampling=sampling, level=level)
        assert arr.shape == ref.shape == (10, 12) and ref.max() > 10
        assert (np.abs(arr - ref) <= bound).all()
        if sampling == "nearest":  # integer means: the level's frame is exact
            assert np.abs(arr - ref).max() < 1e-6
    # the reference of a level is not level 0's picture (the level is really rendered)
    full = hevr.render_plain(volume, cam, sampling=sampling, spacing=SPACING, slices=True)
    assert not np.allclose(full, ref, atol=1.0)


def test_float_volume_levels(tmp_path, keypair512):
    """A float volume's level: the means of the plaintext rounded at digits + 3L, within the bound."""
    priv = keypair512[1]
    f = np.random.default_rng(7).uniform(-1, 1, (9, 7, 6))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ev = hevr.encrypt_volume(
            f,
            tmp_path / "f.zarr",
            priv,
            brick=4,
            layout="packed",
            value_range=(-1, 1),
            digits=2,
            levels=1,
            progress=False,
        )
    view = ev.at_level(1)
    assert view.meta.scalar.digits == 5 and view.packing.offset == -100000
    assert (level_mantissas(view, priv) == np.rint(downsample(f, 1) * 1e5).astype(np.int64)).all()
    cam = hevr.Camera.orbit(ev, azimuth=80, elevation=20, width=9, height=8, parallel=True)
    for sampling in ("nearest", "trilinear"):
        arr = hevr.render(ev, cam, sampling=sampling, level=1, verify=False, progress=False).decrypt(priv)
        ref = hevr.render_plain(f, cam, sampling=sampling, slices=True, level=1)
        assert (np.abs(arr - ref) <= hevr.error_bound(ev, cam, sampling=sampling, level=1)).all()


def test_other_axis_and_public_key(tmp_path, keypair256, volume):
    """Anyone with the public key writes a packed store's levels; packed along x they render too."""
    pub, priv = keypair256
    ev = hevr.encrypt_volume(
        volume, tmp_path / "x.zarr", pub, brick=4, layout="packed", pack_axis="x", levels=1, progress=False
    )
    view = ev.at_level(1)
    assert view.packing.axis == 2 and view.brick[2] % view.packing.slots == 0 and not ev.meta.tags
    assert (level_mantissas(view, priv) == np.rint(downsample(volume, 1) * 1000).astype(np.int64)).all()
    cam = hevr.Camera.orbit(ev, azimuth=0, elevation=25, width=11, height=9, parallel=True)
    arr = hevr.render(ev, cam, sampling="trilinear", level=1, progress=False).decrypt(priv)
    ref = hevr.render_plain(volume, cam, sampling="trilinear", slices="x", level=1)
    assert (np.abs(arr - ref) <= hevr.error_bound(ev, cam, sampling="trilinear", level=1)).all()


def test_interrupted_levels_resume(tmp_path, keypair256, volume, monkeypatch):
    """A run that fails in a level leaves level 0 complete and the level incomplete; resume=True
    encrypts only the level's missing bricks; a later resume can add a level, then is a no-op."""
    priv = keypair256[1]
    path = tmp_path / "r.zarr"
    real = packed_levels._encrypt_level_brick
    calls = []

    def flaky(block, path_, level, index, *args, **kw):
        calls.append((level, index))
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real(block, path_, level, index, *args, **kw)

    monkeypatch.setattr(packed_levels, "_encrypt_level_brick", flaky)
    with pytest.raises(OSError, match="No space left"):
        with dask_sync():
            hevr.encrypt_volume(volume, path, priv, brick=4, layout="packed", levels=1, progress=False)
    monkeypatch.setattr(packed_levels, "_encrypt_level_brick", real)
    ev = hevr.open_volume(path)  # level 0 is complete, level 1 is not
    assert ev.levels == 0 and len(ev.meta.levels) == 1 and not ev.meta.levels[0].complete
    view_meta = ev.meta.level_meta(1)
    again = hevr.encrypt_volume(volume, path, priv, brick=4, layout="packed", levels=1, resume=True, progress=False)
    assert again.levels == 1 and again.meta.store_id == ev.meta.store_id and again.written_now["bricks"] == 0
    total = int(np.prod(view_meta.packing.array_shape(view_meta.shape)))
    assert 0 < again.written_now["ciphertexts"] < total  # only the bricks without markers
    assert (level_mantissas(again.at_level(1), priv) == np.rint(downsample(volume, 1) * 1000)).all()
    more = hevr.encrypt_volume(volume, path, priv, brick=4, layout="packed", levels=2, resume=True, progress=False)
    view2 = more.at_level(2)
    assert more.levels == 2 and more.written_now["ciphertexts"] == int(np.prod(view2.packing.array_shape(view2.shape)))
    done = hevr.encrypt_volume(volume, path, priv, brick=4, layout="packed", levels=2, resume=True, progress=False)
    assert done.written_now == {"bricks": 0, "ciphertexts": 0}


class dask_sync:
    """The synchronous scheduler (the monkeypatched task runs in this process)."""

    def __enter__(self):
        import dask

        self._cfg = dask.config.set(scheduler="synchronous")
        self._cfg.__enter__()

    def __exit__(self, *exc):
        self._cfg.__exit__(*exc)


def _resealed(d: dict) -> dict:
    d = json.loads(json.dumps(d))
    d["checksum"] = metadata_checksum(d)
    return d


def test_level_metadata_round_trip_mac_and_checks(store, keypair512):
    """The levels' layouts round-trip, are bound by the owner's MAC, and are checked against the
    level's shape, exponent, key and brick on reading."""
    meta = store.meta
    d = meta.to_dict()
    assert VolumeMetadata.from_dict(d) == meta
    assert all(lv["layout"]["kind"] == "packed" for lv in d["levels"])
    fields = authenticated_fields(d)
    assert fields["level_layouts"] == [lv["layout"] for lv in d["levels"]]
    assert metadata_mac(keypair512[1], fields) == meta.auth  # the stored MAC covers them
    other = json.loads(json.dumps(d))
    other["levels"][1]["layout"]["slots"] -= 1
    assert metadata_mac(keypair512[1], authenticated_fields(other)) != meta.auth

    def bad(edit, match):
        e = json.loads(json.dumps(d))
        edit(e["levels"][0])
        with pytest.raises(CorruptStoreError, match=match):
            VolumeMetadata.from_dict(_resealed(e))

    bad(lambda lv: lv["layout"].update(slot_bits=lv["layout"]["slot_bits"] - 1), r"levels\[0\].layout.*slot_bits")
    bad(lambda lv: lv["layout"].update(offset="5"), r"levels\[0\].layout.offset: expected 0")
    bad(lambda lv: lv["layout"].update(axis=1), r"levels\[0\].layout.axis: expected 0")
    bad(lambda lv: (lv["layout"].update(slots=200), lv.update(brick=[200, 4, 4])), r"layout.slots: expected at most")
    bad(lambda lv: lv.update(brick=[4, 4, 4]), r"levels\[0\].brick: expected \[")
    bad(lambda lv: lv.pop("layout"), r"levels\[0\]: expected an object with .*'layout'")
    # a per-voxel store's level has no layout
    plain = json.loads(json.dumps(d))
    plain.pop("layout")
    plain["levels"] = plain["levels"][:1]
    plain["levels"][0]["brick"] = list(meta.brick)
    with pytest.raises(CorruptStoreError, match=r"levels\[0\]: expected an object with 'arrays'"):
        VolumeMetadata.from_dict(_resealed(plain))


def test_corrupt_level_brick_is_caught(tmp_path, keypair256, volume):
    ev = hevr.encrypt_volume(
        volume, tmp_path / "c.zarr", keypair256[1], brick=4, layout="packed", levels=1, progress=False
    )
    arr = zarr.open_array(str(tmp_path / "c.zarr") + "/levels/1/scalar", mode="r+")
    rec = arr[0, 0, 0]
    rec[-1] ^= 1
    arr[0, 0, 0] = rec
    with pytest.raises(CorruptStoreError, match="digest mismatch"):
        ev.at_level(1).read_brick((0, 0, 0))


def test_refusals(tmp_path, keypair256, volume, store):
    priv = keypair256[1]
    for bad in (-1, 9, "2", True, 1.0):
        with pytest.raises(ParameterError, match=r"levels: expected an int in \[0, 8\]"):
            hevr.encrypt_volume(volume, tmp_path / "a.zarr", priv, layout="packed", levels=bad, progress=False)
    # each level's slot is about 9 bits wider: level 5's would pass the 62 bits a slot decodes into
    with pytest.raises(ParameterError, match="levels: expected at most 4 levels for this key and value range"):
        hevr.encrypt_volume(volume, tmp_path / "a.zarr", priv, layout="packed", levels=5, progress=False)
    with pytest.raises(ParameterError, match="levels: expected at most"):
        hevr.encrypt_volume(
            np.zeros((4, 4, 4)),
            tmp_path / "a.zarr",
            priv,
            layout="packed",
            levels=2,
            digits=26,
            value_range=(0, 1e-20),
            progress=False,
        )
    assert not (tmp_path / "a.zarr").exists()  # refused before the disk is touched
    # the server still cannot build a packed store's pyramid: the message says how to get one
    with pytest.raises(ParameterError, match=r"cannot downsample across slots.*levels=L"):
        hevr.build_pyramid(store, 1, progress=False)
    cam = hevr.Camera.orbit(store, azimuth=90, width=8, height=8, parallel=True)
    with pytest.raises(ParameterError, match="level: expected a level of this store's pyramid, 0 to 2"):
        hevr.render(store, cam, level=3, verify=False, progress=False)


def test_voxel_store_levels_are_the_servers_pyramid(tmp_path, keypair256, volume, caplog):
    """levels= on a per-voxel store builds its pyramid with hevr.build_pyramid after level 0."""
    with caplog.at_level(logging.WARNING):
        ev = hevr.encrypt_volume(
            volume[:6, :5, :4], tmp_path / "v.zarr", keypair256[1], brick=4, levels=1, progress=False
        )
    assert ev.layout == "voxel" and ev.levels == 1 and ev.meta.levels[0].packing is None
    assert dataclasses.replace(ev.meta.levels[0], complete=True) == ev.meta.levels[0]


@pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")
def test_cli_encrypt_levels_info_and_pyramid(tmp_path, capsys):
    """hevr encrypt --layout packed --levels L writes the levels; hevr info lists them with their
    slots; hevr pyramid on a packed store says to encrypt with --levels."""
    from hevr.cli.main import main

    def run(*argv):
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err

    key, store = tmp_path / "key.json", tmp_path / "p.zarr"
    assert run("keygen", "--bits", "256", "--out", key)[0] == 0
    code, out, _ = run(
        "encrypt", "phantom:12", "--key", key, "--out", store, "--layout", "packed", "--brick", "4", "--levels", "2"
    )
    assert code == 0 and "level 2:" in out
    ev = hevr.open_volume(store)
    assert ev.levels == 2 and all(lv.packing is not None for lv in ev.meta.levels)
    priv = hevr.load_key(key)
    cam = hevr.Camera.orbit(ev, azimuth=90, elevation=15, width=9, height=9, parallel=True)
    img = hevr.render(ev, cam, level=2, progress=False, verify=False)
    ref = hevr.render_plain(hevr.phantom(12), cam, slices=True, level=2)
    assert (np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(ev, cam, level=2)).all()
    code, out, _ = run("info", store)
    lv1 = ev.meta.levels[0].packing
    assert code == 0 and f"packed: {lv1.slots} voxels per ciphertext ({lv1.slot_bits}-bit slots), complete" in out
    code, out, _ = run("pyramid", store, "--levels", "2")
    assert code == 0 and "nothing to do" in out  # the owner's levels are there
    code, _, err = run("pyramid", store, "--levels", "3")
    assert code != 0 and "--levels" in err and "cannot downsample across slots" in err


def test_verified_level_frames(store, keypair512, volume):
    """A verifiable store's level frame passes the key holder's check (hevr.rendering.packed.verified)
    with the level's own tags, and is the frame of the unverified render."""
    priv = keypair512[1]
    cam = hevr.Camera.orbit(store, azimuth=60, elevation=10, width=12, height=10, parallel=True)
    for level in (1, 2):
        img = hevr.render(store, cam, sampling="trilinear", level=level, verify=True, progress=False)
        arr = img.decrypt(priv)  # checked against the tags before any pixel is returned
        plain = hevr.render(store, cam, sampling="trilinear", level=level, verify=False, progress=False)
        assert (arr == plain.decrypt(priv)).all()
        ref = hevr.render_plain(volume, cam, sampling="trilinear", spacing=SPACING, slices=True, level=level)
        assert (np.abs(arr - ref) <= hevr.error_bound(store, cam, sampling="trilinear", level=level)).all()


def test_overwrite_writes_levels_beside_then_swaps(tmp_path, keypair256, volume):
    """overwrite=True: the new store's levels are written beside the old store and swapped in with it."""
    priv = keypair256[1]
    path = tmp_path / "o.zarr"
    old = hevr.encrypt_volume(volume, path, priv, brick=4, layout="packed", levels=1, progress=False)
    other = (255 - volume).astype(np.uint8)
    new = hevr.encrypt_volume(other, path, priv, brick=4, layout="packed", levels=2, overwrite=True, progress=False)
    assert new.meta.store_id != old.meta.store_id and new.levels == 2
    for L in (1, 2):
        want = np.rint(downsample(other, L) * 1000**L).astype(np.int64)
        assert (level_mantissas(new.at_level(L), priv) == want).all()
    assert [p.name for p in tmp_path.iterdir()] == ["o.zarr"]  # nothing left beside it
