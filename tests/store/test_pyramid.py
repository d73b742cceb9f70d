"""The encrypted pyramid (hevr.store.pyramid) against the plaintext definition
(hevr.volume.pyramid.downsample): every level voxel decrypts to the clamped 2×2×2 mean of the
level below, exactly; the store stays checked (digests per level, metadata, OME attribute);
building resumes; bad requests are named."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import zarr

import hevr
from hevr.store import pyramid as pyr
from hevr.store.digests import written
from hevr.volume.density import encode_density, normalize_density
from hevr.volume.pyramid import downsample, level_origin, level_shape

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _decrypt_level(lv, priv, channel):
    k = 1 if channel == "scalar" else lv.vector_dims
    out = np.zeros(lv.shape + (k,))
    info = lv.meta.scalar if channel == "scalar" else lv.meta.vector
    for idx in lv.brick_indices():
        got = lv.read_brick(idx, channel)
        batches = [got] if channel == "scalar" else got
        sl = lv.brick_slices(idx)
        for j, b in enumerate(batches):
            vals = np.array([priv.decrypt(c) for c in b], dtype=np.float64)
            out[sl + (j,)] = vals.reshape(lv.brick_shape(idx)) * 10.0**info.exponent
    return out[..., 0] if channel == "scalar" else out


@pytest.fixture(scope="module")
def built(tmp_path_factory, keypair256):
    """An odd-shaped uint8 volume (edge clamping on every axis) with both channels, bricks of 3."""
    pub, priv = keypair256
    vol = np.random.default_rng(4).integers(0, 256, (7, 9, 10)).astype(np.uint8)
    path = tmp_path_factory.mktemp("pyr") / "v.zarr"
    hevr.encrypt_volume(vol, path, priv, brick=3, vector_dims=3, spacing=(1.0, 2.0, 0.5), progress=False)
    ev = pyr.build_pyramid(path, 2, progress=False)
    return ev, priv, vol


def test_levels_decrypt_to_the_clamped_means(built):
    ev, priv, vol = built
    assert ev.levels == 2 and [lv.shape for lv in ev.meta.levels] == [(4, 5, 5), (2, 3, 3)]
    enc = np.rint(encode_density(normalize_density(vol, ev.value_range), 3) * 1000) / 1000  # the stored vectors
    for L in (1, 2):
        lv = ev.at_level(L)
        assert lv.shape == level_shape(vol.shape, L) and lv.spacing == (2.0**L, 2.0 ** (L + 1), 0.5 * 2**L)
        assert lv.origin == level_origin((1.0, 2.0, 0.5), L) and lv.brick == ev.brick
        assert lv.meta.scalar.exponent == -3 * L and lv.meta.vector.digits == 3 + 3 * L
        np.testing.assert_allclose(_decrypt_level(lv, priv, "scalar"), downsample(vol, L), rtol=0, atol=1e-9)
        np.testing.assert_allclose(_decrypt_level(lv, priv, "vector"), downsample(enc, L), rtol=0, atol=1e-12)


def test_metadata_and_ome_attribute(built):
    ev, _, _ = built
    group = zarr.open_group(ev.path, mode="r")
    ome = group.attrs["ome"]
    assert [m["name"] for m in ome["multiscales"]] == ["scalar", "vector"]
    ds = ome["multiscales"][0]["datasets"]
    assert [d["path"] for d in ds] == ["scalar", "levels/1/scalar", "levels/2/scalar"]
    assert ds[2]["coordinateTransformations"] == [
        {"type": "scale", "scale": [2.0, 8.0, 4.0, 1.0]},
        {"type": "translation", "translation": [0.75, 3.0, 1.5, 0.0]},
    ]
    again = hevr.open_volume(ev.path, verify="full")
    assert again.meta.levels == ev.meta.levels
    assert hevr.store.metadata.VolumeMetadata.from_dict(ev.meta.to_dict()) == ev.meta


def test_every_level_is_checked_on_read(built, tmp_path):
    ev, priv, vol = built
    copy = tmp_path / "c.zarr"
    shutil.copytree(ev.path, copy)
    chunk = next(p for p in sorted((copy / "levels" / "1" / "scalar" / "c").rglob("*")) if p.is_file())
    blob = bytearray(chunk.read_bytes())
    blob[10] ^= 1
    chunk.write_bytes(bytes(blob))
    lv = hevr.open_volume(copy).at_level(1)
    bad = tuple(int(p) for p in chunk.relative_to(copy / "levels" / "1" / "scalar" / "c").parts[:3])
    with pytest.raises(hevr.CorruptStoreError, match=r"level 1"):
        lv.read_brick(bad, "scalar")
    # a level brick swapped into level 0 (same index, same store) fails its digest
    shutil.rmtree(copy)
    shutil.copytree(ev.path, copy)
    (copy / "scalar" / "c" / "0" / "0" / "0" / "0").write_bytes(
        (copy / "levels" / "1" / "scalar" / "c" / "0" / "0" / "0" / "0").read_bytes()
    )
    (copy / "done" / "c" / "0" / "0" / "0" / "0" / "0").write_bytes(
        (copy / "levels" / "1" / "done" / "c" / "0" / "0" / "0" / "0" / "0").read_bytes()
    )
    with pytest.raises(hevr.CorruptStoreError, match="digest mismatch"):
        hevr.open_volume(copy).read_brick((0, 0, 0), "scalar")
    # the OME attribute is pinned by the checksummed metadata
    shutil.rmtree(copy)
    shutil.copytree(ev.path, copy)
    doc = json.loads((copy / "zarr.json").read_text())
    doc["attributes"]["ome"]["multiscales"][0]["datasets"][1]["path"] = "elsewhere"
    (copy / "zarr.json").write_text(json.dumps(doc))
    with pytest.raises(hevr.CorruptStoreError, match="'ome' attribute"):
        hevr.open_volume(copy)
    # a level array's document is pinned too
    shutil.rmtree(copy)
    shutil.copytree(ev.path, copy)
    doc = json.loads((copy / "levels" / "2" / "vector" / "zarr.json").read_text())
    doc["fill_value"] = 1
    (copy / "levels" / "2" / "vector" / "zarr.json").write_text(json.dumps(doc))
    with pytest.raises(hevr.CorruptStoreError, match="levels/2/vector"):
        hevr.open_volume(copy).at_level(2)


def test_resume_and_more_levels(tmp_path, keypair256, monkeypatch):
    pub, priv = keypair256
    vol = hevr.phantom(12)
    path = tmp_path / "p.zarr"
    hevr.encrypt_volume(vol, path, pub, brick=4, progress=False)
    calls = []
    real = pyr._level_brick

    def flaky(below, p, level, index, meta, backend):
        calls.append((level, index))
        if len(calls) == 5:  # a few bricks are written by then
            raise RuntimeError("worker lost")
        return real(below, p, level, index, meta, backend)

    monkeypatch.setattr(pyr, "_level_brick", flaky)
    with pytest.raises(RuntimeError, match="worker lost"):
        pyr.build_pyramid(path, 1, progress=False)
    ev = hevr.open_volume(path)  # level 0 is untouched and opens; the level is not complete
    assert ev.levels == 0 and len(ev.meta.levels) == 1 and not ev.meta.levels[0].complete
    with pytest.raises(hevr.ParameterError, match="level: expected a level of this store's pyramid, 0 to 0"):
        ev.at_level(1)
    done = written(zarr.open_group(path, mode="r")["levels/1/done"][...])
    missing = sorted((1, tuple(int(i) for i in idx)) for idx in zip(*np.nonzero(~done)))
    assert calls[4] in missing and 1 <= len(missing) < 8
    failed = calls[4]
    calls.clear()
    monkeypatch.setattr(pyr, "_level_brick", lambda *a: calls.append(a[2:4]) or real(*a))
    ev = pyr.build_pyramid(path, 1, progress=False)
    # only missing bricks (a task still running when the first failed may have finished since)
    assert ev.levels == 1 and set(calls) <= set(missing) and failed in calls and len(calls) < 8
    calls.clear()
    ev = pyr.build_pyramid(ev, 3, progress=False)
    assert ev.levels == 3 and {c[0] for c in calls} == {2, 3}  # level 1 kept
    np.testing.assert_allclose(_decrypt_level(ev.at_level(3), priv, "scalar"), downsample(vol, 3), rtol=0, atol=1e-9)


def test_bad_requests(built, tmp_path, keypair256):
    ev, _, _ = built
    for bad in (0, 9, 1.0, True, "2"):
        with pytest.raises(hevr.ParameterError, match="levels: expected an int in"):
            pyr.build_pyramid(ev, bad)
    with pytest.raises(hevr.ParameterError, match="level: expected a level of this store's pyramid, 0 to 2, got 3"):
        ev.at_level(3)
    with pytest.raises(hevr.ParameterError, match="ev: expected a store"):
        pyr.build_pyramid(ev.at_level(1), 1)
    vol = np.linspace(0, 1, 64, dtype=np.float32).reshape(4, 4, 4)
    fev = hevr.encrypt_volume(vol, tmp_path / "f.zarr", keypair256[0], brick=4, digits=12, progress=False)
    with pytest.raises(hevr.ParameterError, match="levels: expected at most 6 levels for a channel of 12 digits"):
        pyr.build_pyramid(fev, 7)


def test_opening_checks_every_complete_level(built, tmp_path):
    """open_volume (quick) checks each complete level's layout and chunk files; verify='full' reads
    every level's ciphertexts: a level that lost a chunk is named, not reported as fine."""
    ev, _, _ = built
    copy = tmp_path / "c.zarr"
    shutil.copytree(ev.path, copy)
    assert hevr.open_volume(copy, verify="full").levels == 2
    victim = next(p for p in sorted((copy / "levels" / "2" / "vector" / "c").rglob("*")) if p.is_file())
    victim.unlink()
    with pytest.raises(hevr.CorruptStoreError, match="missing chunk"):
        hevr.open_volume(copy)
    assert hevr.open_volume(copy, verify="none").levels == 2  # forensics still open it
