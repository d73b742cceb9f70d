"""hevr.store.reader: open_volume's checks (missing, foreign, incomplete, corrupt stores) and
EncryptedVolume's brick reads, compared with decrypting to the plaintext mantissas."""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr

import hevr
from hevr.store.digests import brick_digest
from hevr.store.metadata import metadata_checksum
from hevr.store.reader import EncryptedVolume, brick_slices
from hevr.volume.density import encode_density, normalize_density

SHAPE = (5, 7, 9)
BRICK = (2, 3, 4)  # 3 x 3 x 3 bricks, ragged at every edge
GRID = (3, 3, 3)


def _hand_slices(idx):
    """The voxels brick ``idx`` owns, written out for SHAPE / BRICK."""
    return tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(idx, BRICK, SHAPE))


def _records(arr, width):
    """Big-endian records -> Python ints, without hevr."""
    flat = np.ascontiguousarray(arr, dtype=np.uint8).reshape(-1, width)
    return [int.from_bytes(row.tobytes(), "big") for row in flat]


@pytest.fixture()
def small_store(tmp_path, keypair256):
    vol = np.random.default_rng(7).integers(0, 256, SHAPE).astype(np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[1], brick=BRICK, progress=False)
    return Path(ev.path)


@pytest.fixture(scope="module")
def signed_store(tmp_path_factory, keypair256):
    """int16 volume (scalar exponent 0: the plaintext is the voxel value) plus a 3-vector
    channel with 2 digits, encrypted with the public key."""
    pub, _ = keypair256
    vol = np.random.default_rng(3).integers(-500, 500, SHAPE).astype(np.int16)
    path = tmp_path_factory.mktemp("reader") / "signed.zarr"
    hevr.encrypt_volume(
        vol, path, pub, brick=BRICK, spacing=(1.0, 2.0, 0.5), vector_dims=3, vector_digits=2, progress=False
    )
    return hevr.open_volume(path), vol


def _chunk(path, idx):
    return path / "scalar" / "c" / "/".join(str(i) for i in idx + (0,))


def _edit_attrs(store, edit, checksum=True):
    """Edit the ``hevr`` attribute; with ``checksum`` recompute it, as a crafted store would."""
    meta = json.loads((store / "zarr.json").read_text())
    edit(meta["attributes"]["hevr"])
    if checksum:
        meta["attributes"]["hevr"]["checksum"] = metadata_checksum(meta["attributes"]["hevr"])
    (store / "zarr.json").write_text(json.dumps(meta))


def _craft_brick(store, idx, edit):
    """Rewrite brick ``idx``'s scalar records through Zarr (valid crc32c) and its digest, as a
    crafted store would: only the range checks are left to catch what ``edit`` did."""
    ev = hevr.open_volume(store, verify="none")
    sl = ev.brick_slices(idx)
    arr = zarr.open_array(str(store / "scalar"), mode="r+")
    recs = np.array(arr[sl])
    edit(recs)
    arr[sl] = recs
    done = zarr.open_array(str(store / "done"), mode="r+")
    digests = np.array(done[idx])
    digests[0] = np.frombuffer(brick_digest(ev.meta.store_id, "scalar", idx, recs), np.uint8)
    done[idx] = digests


# -- reading bricks ------------------------------------------------------------------------


def test_public_metadata_of_an_opened_store(signed_store, keypair256):
    ev, _ = signed_store
    pub, priv = keypair256
    assert (ev.shape, ev.brick, ev.grid, ev.spacing) == (SHAPE, BRICK, GRID, (1.0, 2.0, 0.5))
    assert ev.has_scalar and ev.vector_dims == 3 and ev.dtype == np.dtype(np.int16)
    assert ev.value_range == (-32768.0, 32767.0)  # int16 default: the dtype's full range
    assert ev.public_key == pub and ev.meta.fingerprint == pub.fingerprint
    assert ev.meta.ciphertext_bytes == 2 * 256 // 8
    assert ev.brick_indices() == [(i, j, k) for i in range(3) for j in range(3) for k in range(3)]
    text = repr(ev)
    assert ev.path in text and pub.fingerprint[:16] in text
    assert str(int(priv.p)) not in text and str(int(priv.q)) not in text


def test_brick_slices_and_shapes_match_hand_computed(signed_store):
    ev, _ = signed_store
    assert ev.brick_slices((2, 2, 2)) == (slice(4, 5), slice(6, 7), slice(8, 9))
    assert ev.brick_shape((2, 2, 2)) == (1, 1, 1) and ev.brick_shape((0, 0, 0)) == BRICK
    for idx in ev.brick_indices():
        assert ev.brick_slices(idx) == _hand_slices(idx) == brick_slices(ev.meta, idx)
    assert sum(np.prod(ev.brick_shape(i)) for i in ev.brick_indices()) == np.prod(SHAPE)


def test_scalar_bricks_decrypt_to_the_voxel_values(signed_store, keypair256):
    ev, vol = signed_store
    _, priv = keypair256
    n2 = int(ev.public_key.n) ** 2
    for idx in ev.brick_indices():
        cts = ev.read_brick(idx)
        block = vol[_hand_slices(idx)]
        assert len(cts) == block.size
        assert all(0 < int(c) < n2 for c in cts)
        assert priv.decrypt_array(cts) == block.ravel().astype(int).tolist()


def test_vector_bricks_decrypt_to_the_encoded_density(signed_store, keypair256):
    ev, vol = signed_store
    _, priv = keypair256
    for idx in [(0, 0, 0), (1, 2, 1), (2, 2, 2)]:
        block = vol[_hand_slices(idx)]
        expected = np.rint(encode_density(normalize_density(block, ev.value_range), 3) * 100).astype(np.int64)
        lists = ev.read_brick(idx, "vector")
        assert len(lists) == 3
        for j, cts in enumerate(lists):
            assert priv.decrypt_array(cts) == expected[..., j].ravel().tolist()


def test_read_brick_is_the_stored_big_endian_records(signed_store):
    ev, _ = signed_store
    w = ev.meta.ciphertext_bytes
    for idx in [(0, 0, 0), (2, 1, 2)]:
        sl = _hand_slices(idx)
        raw = np.asarray(zarr.open_array(f"{ev.path}/scalar", mode="r")[sl])
        got = ev.read_brick_bytes(idx)
        assert got.shape == ev.brick_shape(idx) + (w,) and got.dtype == np.uint8
        assert np.array_equal(got, raw)
        assert [int(c) for c in ev.read_brick(idx)] == _records(raw, w)
        vec = ev.read_brick_bytes(idx, "vector")
        assert vec.shape == (3,) + ev.brick_shape(idx) + (w,)
        assert [[int(c) for c in cts] for cts in ev.read_brick(idx, "vector")] == [_records(v, w) for v in vec]


def test_ciphertexts_are_randomised(signed_store):
    ev, vol = signed_store
    cts = [int(c) for idx in ev.brick_indices() for c in ev.read_brick(idx)]
    assert len(cts) == vol.size and len(set(cts)) == len(cts)


@pytest.mark.parametrize(
    "args, match",
    [
        (((0, 0, 0), "rgb"), "channel: expected 'scalar', 'vector' or 'gradient'"),
        (((3, 0, 0), "scalar"), r"inside the grid \(3, 3, 3\)"),
        (((0, -1, 0), "scalar"), "inside the grid"),
        (((0, 0), "scalar"), "brick index"),
    ],
)
def test_read_brick_bad_arguments(signed_store, args, match):
    ev, _ = signed_store
    with pytest.raises(hevr.ParameterError, match=match):
        ev.read_brick(*args)


def test_read_missing_channel_is_refused(small_store):
    ev = hevr.open_volume(small_store)
    assert ev.vector_dims is None
    with pytest.raises(hevr.ParameterError, match="no vector channel"):
        ev.read_brick((0, 0, 0), "vector")


def test_handle_pickles_as_path_and_metadata(signed_store):
    ev, _ = signed_store
    blob = pickle.dumps(ev)
    assert len(blob) < 4096  # no arrays, no ciphertexts: cheap to ship in every Dask task
    back = pickle.loads(blob)
    assert isinstance(back, EncryptedVolume) and back.path == ev.path and back.meta == ev.meta
    assert [int(c) for c in back.read_brick((1, 1, 1))] == [int(c) for c in ev.read_brick((1, 1, 1))]


def test_relative_path_opens_as_absolute(small_store, monkeypatch):
    monkeypatch.chdir(small_store.parent)
    ev = hevr.open_volume(small_store.name)
    assert Path(ev.path).is_absolute() and Path(ev.path) == small_store


# -- open_volume: what is refused ------------------------------------------------------------


def test_missing_store_is_a_file_not_found_hevr_error(tmp_path):
    missing = tmp_path / "nope.zarr"
    with pytest.raises(FileNotFoundError) as info:
        hevr.open_volume(missing)
    assert isinstance(info.value, hevr.HevrError)
    assert str(missing) in str(info.value)
    assert not missing.exists()


def test_bad_verify_argument(small_store):
    with pytest.raises(hevr.ParameterError, match="verify"):
        hevr.open_volume(small_store, verify="fast")


@pytest.mark.parametrize("content", [None, b"{not json"], ids=["empty-dir", "garbage-zarr-json"])
def test_not_a_zarr_group(tmp_path, content):
    d = tmp_path / "x.zarr"
    d.mkdir()
    if content is not None:
        (d / "zarr.json").write_bytes(content)
    with pytest.raises(hevr.CorruptStoreError, match=str(d)):
        hevr.open_volume(d)


def test_wrong_key_fingerprint_is_refused(small_store, keypair512):
    """The modulus of another key under this store's fingerprint: the pair no longer matches."""

    def swap(meta):
        meta["public_key"]["n"] = str(int(keypair512[0].n))
        meta["public_key"]["bits"] = 512

    _edit_attrs(small_store, swap)
    with pytest.raises(hevr.CorruptStoreError, match="fingerprint does not match"):
        hevr.open_volume(small_store, verify="none")


def test_ciphertext_width_must_match_key(small_store):
    _edit_attrs(small_store, lambda m: m.update(ciphertext_bytes=m["ciphertext_bytes"] + 1))
    with pytest.raises(hevr.CorruptStoreError, match="ciphertext_bytes is 65, expected 64"):
        hevr.open_volume(small_store)


def test_metadata_shape_inconsistent_with_array(small_store):
    _edit_attrs(small_store, lambda m: m.update(shape=[5, 7, 8], n_bricks=18))
    with pytest.raises(hevr.CorruptStoreError, match="array 'scalar' has shape .*inconsistent"):
        hevr.open_volume(small_store)


def test_declared_channel_array_missing(small_store):
    shutil.rmtree(small_store / "scalar")
    with pytest.raises(hevr.CorruptStoreError, match="channel 'scalar' is declared but its array is missing"):
        hevr.open_volume(small_store)


def _mark_incomplete(store, missing):
    _edit_attrs(store, lambda m: m.update(complete=False))
    group = zarr.open_group(str(store), mode="r+")
    for idx in missing:
        group["done"][idx] = 0


@pytest.mark.parametrize("verify", ["quick", "none"])
def test_incomplete_store_names_missing_bricks(small_store, verify):
    _mark_incomplete(small_store, [(0, 0, 0), (2, 1, 0)])
    with pytest.raises(hevr.IncompleteStoreError, match="2 of 27 bricks missing") as info:
        hevr.open_volume(small_store, verify=verify)
    assert isinstance(info.value, hevr.StoreError) and "resume=True" in str(info.value)


def test_incomplete_store_without_markers_counts_every_brick(small_store):
    _mark_incomplete(small_store, [])
    shutil.rmtree(small_store / "done")
    with pytest.raises(hevr.IncompleteStoreError, match="27 of 27 bricks missing"):
        hevr.open_volume(small_store)


# -- corruption -------------------------------------------------------------------------------


def test_corrupt_wrong_version(small_store):
    meta = json.loads((small_store / "zarr.json").read_text())
    meta["attributes"]["hevr"]["version"] = 99
    (small_store / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(hevr.CorruptStoreError, match="version 99"):
        hevr.open_volume(small_store)


def test_corrupt_foreign_group(tmp_path):
    zarr.open_group(tmp_path / "foreign.zarr", mode="w").attrs["x"] = 1
    with pytest.raises(hevr.CorruptStoreError, match="not an hevr encrypted volume"):
        hevr.open_volume(tmp_path / "foreign.zarr")


def test_corrupt_missing_chunk(small_store):
    _chunk(small_store, (1, 2, 0)).unlink()
    with pytest.raises(hevr.CorruptStoreError, match=r"missing chunk for brick \(1, 2, 0\)"):
        hevr.open_volume(small_store)
    ev = hevr.open_volume(small_store, verify="none")
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 2, 0\).*digest mismatch"):
        ev.read_brick((1, 2, 0))


def test_read_brick_without_check_returns_the_raw_zeros(small_store):
    _chunk(small_store, (1, 2, 0)).unlink()
    ev = hevr.open_volume(small_store, verify="none")
    cts = ev.read_brick((1, 2, 0), check=False)
    assert len(cts) == np.prod(ev.brick_shape((1, 2, 0))) and all(c == 0 for c in cts)


@pytest.mark.parametrize("cut", [slice(None, -5), slice(None, -3000), slice(None, 40)])
def test_corrupt_truncated_chunk(small_store, cut):
    """A zstd chunk has no fixed size; its frame's block headers give its length."""
    f = _chunk(small_store, (0, 1, 1))
    f.write_bytes(f.read_bytes()[cut])
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(0, 1, 1\).*truncated"):
        hevr.open_volume(small_store)
    ev = hevr.open_volume(small_store, verify="none")
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(0, 1, 1\).*cannot be read"):
        ev.read_brick((0, 1, 1))


def test_corrupt_ciphertext_too_large(small_store):
    """A crafted brick (valid crc32c and digest) of records >= n²: the range check names it."""
    _craft_brick(small_store, (2, 0, 1), lambda recs: recs.fill(0xFF))
    ev = hevr.open_volume(small_store)  # sizes, crc and digests are right: quick verify passes
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(2, 0, 1\).*>= n²"):
        ev.read_brick((2, 0, 1))
    with pytest.raises(hevr.CorruptStoreError, match=r"\(2, 0, 1\)"):
        hevr.open_volume(small_store, verify="full")


def test_corrupt_not_coprime(small_store, keypair256):
    pub, _ = keypair256
    w = pub.ciphertext_bytes

    def put_n(recs):  # c = n: in range but not a unit
        recs.reshape(-1, w)[0] = np.frombuffer(int(pub.n).to_bytes(w, "big"), np.uint8)

    _craft_brick(small_store, (1, 1, 1), put_n)
    with pytest.raises(hevr.CorruptStoreError, match=r"\(1, 1, 1\).*coprime"):
        hevr.open_volume(small_store, verify="full")


def test_fingerprint_must_match_modulus(small_store):
    _edit_attrs(small_store, lambda m: m["public_key"].update(fingerprint="0" * 64))
    with pytest.raises(hevr.CorruptStoreError, match="fingerprint"):
        hevr.open_volume(small_store)


def test_metadata_edit_without_checksum_is_refused(small_store):
    _edit_attrs(small_store, lambda m: m.update(value_range=[0.0, 256.0]), checksum=False)
    with pytest.raises(hevr.CorruptStoreError, match="metadata checksum mismatch"):
        hevr.open_volume(small_store, verify="none")
