"""Packed stores (hevr.store.packing): slot maths, metadata, writer, reader, tags."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest
import zarr
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr
from hevr.crypto.tags import betas, raw_tags, tag_key_of
from hevr.errors import CorruptStoreError, ParameterError
from hevr.store.authenticity import authenticated_fields, metadata_mac
from hevr.store.metadata import VolumeMetadata
from hevr.store.packing import (
    INTEGRITY_BITS,
    PackingInfo,
    choose_packing,
    max_slots,
    pack_columns,
    slot_bits,
    unpack_slots,
)


# -- slot maths --------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 20), st.integers(0, 2), st.data())
def test_pack_unpack_round_trip(S, K, axis, data):
    """Packing columns then reading the slots back gives every voxel, ragged ends as 0."""
    shape = [data.draw(st.integers(1, 7)) for _ in range(3)]
    lo = data.draw(st.integers(-50, 50))
    vals = (
        np.array(
            data.draw(
                st.lists(st.integers(0, (1 << K) - 1), min_size=int(np.prod(shape)), max_size=int(np.prod(shape)))
            )
        ).reshape(shape)
        + lo
    )
    info = PackingInfo(axis=axis, slots=S, slot_bits=K, weight_bits=0, offset=lo)
    packed = pack_columns(vals, info)
    assert packed.shape == info.array_shape(tuple(shape))
    cols = np.moveaxis(packed, axis, -1)
    slots = unpack_slots(cols.ravel().tolist(), S, K).reshape(cols.shape + (S,))
    back = slots.reshape(cols.shape[:-1] + (-1,))[..., : shape[axis]]
    assert (np.moveaxis(back, -1, axis) == vals - lo).all()
    if shape[axis] % S:  # the ragged end of each column is empty
        assert (slots.reshape(cols.shape[:-1] + (-1,))[..., shape[axis] :] == 0).all()


def test_pack_refuses_values_outside_slots():
    info = PackingInfo(axis=0, slots=2, slot_bits=4, weight_bits=0, offset=0)
    with pytest.raises(ParameterError, match="mantissas: expected slot values in"):
        pack_columns(np.array([[[16]]]), info)
    with pytest.raises(ParameterError, match="mantissas"):
        pack_columns(np.array([[[-1]]]), info)


def test_slot_choice_fits_key_and_margin():
    # 12-bit values, 512 slices at 2048 bits: S = 31 with 10-bit weights (the design note's 8 + 8 bits: S = 27)
    assert slot_bits(4095, 10, 512) == 32 and max_slots(2048, 32) == 31 and max_slots(2048, 37) == 27
    for bits in (256, 512, 1024, 2048):
        for k in (10, 30, 37):
            s = max_slots(bits, k)
            if s:
                assert k * (2 * s - 1) <= bits - 1 - INTEGRITY_BITS < k * (2 * (s + 1) - 1)
    info = choose_packing(2048, (300, 512, 512), 0, (-1024, 3071))
    assert (info.slots, info.slot_bits, info.offset) == (31, 32, -1024)
    with pytest.raises(ParameterError, match="layout: expected a key with room"):
        choose_packing(96, (8, 8, 8), 0, (0, 255))
    with pytest.raises(ParameterError, match="value_range"):
        choose_packing(4096, (8, 8, 8), 0, (0, 2**60))


# -- stores ------------------------------------------------------------------------------------
SHAPE = (11, 6, 7)  # z not a multiple of the slots: a ragged last pack


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def packed(tmp_path_factory, keypair512, volume):
    path = tmp_path_factory.mktemp("packed") / "p.zarr"
    return hevr.encrypt_volume(
        volume, path, keypair512[1], brick=(4, 4, 4), layout="packed", verifiable=True, progress=False
    )


def _voxels(ev, priv):
    """The volume decrypted from a packed store, brick by brick."""
    info = ev.packing
    out = np.zeros(ev.shape, np.int64)
    for idx in ev.brick_indices():
        sl = ev.brick_slices(idx)
        vals = priv.decrypt_array(ev.read_brick(idx))
        rec = [s.stop - s.start for s in sl]
        rec[info.axis] = -(-rec[info.axis] // info.slots)
        slots = unpack_slots(vals, info.slots, info.slot_bits).reshape(rec + [info.slots])
        cols = np.moveaxis(slots, info.axis, -2).reshape(*[r for i, r in enumerate(rec) if i != info.axis], -1)
        block = np.moveaxis(cols[..., : sl[info.axis].stop - sl[info.axis].start], -1, info.axis)
        out[sl] = block + info.offset
    return out


def test_packed_store_holds_every_voxel(packed, keypair512, volume):
    ev = hevr.open_volume(packed.path, verify="full")
    assert ev.layout == "packed" and ev.meta.packing == packed.packing
    S = ev.packing.slots
    assert ev.brick[0] % S == 0  # the brick's packing edge was rounded up to whole packs
    assert (_voxels(ev, keypair512[1]) == volume).all()
    # one record per pack: about S times fewer ciphertexts than voxels
    arr = zarr.open_array(str(packed.path) + "/scalar", mode="r")
    assert arr.shape[:3] == (-(-SHAPE[0] // S), SHAPE[1], SHAPE[2])
    assert "layout=packed" in repr(ev)


def test_packed_tags_one_per_pack(packed, keypair512):
    priv = keypair512[1]
    ev = packed
    key = tag_key_of(priv)
    idx = (0, 1, 1)
    data = [int(priv.raw_decrypt(c)) for c in ev.read_brick(idx)]
    tags = [int(priv.raw_decrypt(c)) for c in ev.read_brick(idx, "scalar_tag")]
    from hevr.store.layout import array_slices

    sl = array_slices(ev.meta, idx)
    packs = np.ravel_multi_index(
        np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"), ev.packing.array_shape(ev.shape)
    ).reshape(-1)
    assert tags == raw_tags(key, data, betas(key, ev.meta.store_id, "scalar", 0, 0, packs))
    assert len(tags) == len(packs) == int(np.prod([s.stop - s.start for s in sl]))


def test_packed_metadata_round_trip_and_mac(packed, keypair512):
    meta = packed.meta
    d = meta.to_dict()
    assert d["layout"]["kind"] == "packed" and isinstance(d["layout"]["offset"], str)
    assert VolumeMetadata.from_dict(d) == meta
    # the owner's MAC covers the layout: other slots give another MAC
    fields = authenticated_fields(d)
    assert fields["layout"] == d["layout"]
    other = dict(d, layout=dict(d["layout"], slots=d["layout"]["slots"] - 1))
    assert metadata_mac(keypair512[1], authenticated_fields(other)) != meta.auth
    # per-voxel stores' bound fields are unchanged (no 'layout' key): their MACs still hold
    plain = {k: v for k, v in d.items() if k != "layout"}
    assert "layout" not in authenticated_fields(plain)


def _resealed(d: dict, **layout) -> dict:
    from hevr.store.metadata import metadata_checksum

    d = json.loads(json.dumps(d))
    d["layout"].update(layout)
    d["checksum"] = metadata_checksum(d)
    return d


def test_packed_metadata_refuses_inconsistent_layout(packed):
    d = packed.meta.to_dict()
    K = d["layout"]["slot_bits"]
    with pytest.raises(CorruptStoreError, match="layout.slot_bits: expected at least"):
        VolumeMetadata.from_dict(_resealed(d, slot_bits=K - 1))  # sums could carry into the next slot
    with pytest.raises(CorruptStoreError, match="layout.slots: expected at most"):
        VolumeMetadata.from_dict(_resealed(d, slots=200))
    with pytest.raises(CorruptStoreError, match="layout.offset"):
        VolumeMetadata.from_dict(_resealed(d, offset="7"))
    with pytest.raises(CorruptStoreError, match="brick: expected a multiple of layout.slots"):
        VolumeMetadata.from_dict(_resealed(d, slots=d["layout"]["slots"] - 1))
    with pytest.raises(CorruptStoreError, match="layout: expected an object"):
        VolumeMetadata.from_dict(_resealed(d, kind="voxel"))


def test_encrypt_packed_parameters(tmp_path, keypair256, volume):
    priv = keypair256[1]
    with pytest.raises(ParameterError, match="layout: expected one of"):
        hevr.encrypt_volume(volume, tmp_path / "a.zarr", priv, layout="slots", progress=False)
    with pytest.raises(ParameterError, match="layout: expected 'voxel' for a store without the scalar channel"):
        hevr.encrypt_volume(
            volume, tmp_path / "a.zarr", priv, layout="packed", vector_dims=4, scalar=False, progress=False
        )
    with pytest.raises(ParameterError, match="pack_axis: expected None for layout='voxel'"):
        hevr.encrypt_volume(volume, tmp_path / "a.zarr", priv, pack_axis="x", progress=False)
    with pytest.raises(ParameterError, match="pack_axis: expected 0, 1, 2"):
        hevr.encrypt_volume(volume, tmp_path / "a.zarr", priv, layout="packed", pack_axis="w", progress=False)
    assert not (tmp_path / "a.zarr").exists()  # refused before the disk is touched


def test_packed_store_other_axis_and_resume(tmp_path, keypair256, volume):
    priv = keypair256[1]
    path = tmp_path / "x.zarr"
    ev = hevr.encrypt_volume(volume, path, priv, brick=3, layout="packed", pack_axis="x", progress=False)
    assert ev.packing.axis == 2 and ev.brick[2] % ev.packing.slots == 0
    assert (_voxels(ev, priv) == volume).all()
    again = hevr.encrypt_volume(
        volume, path, priv, brick=3, layout="packed", pack_axis="x", resume=True, progress=False
    )
    assert again.written_now["bricks"] == 0 and again.meta.store_id == ev.meta.store_id


def test_packed_float_and_signed_volumes(tmp_path, keypair512):
    """Signed integers and float volumes pack their offset mantissas exactly."""
    priv = keypair512[1]
    vol = np.random.default_rng(2).integers(-1024, 3072, (5, 4, 3)).astype(np.int16)
    ev = hevr.encrypt_volume(
        vol, tmp_path / "s.zarr", priv, brick=4, layout="packed", value_range=(-1024, 3071), progress=False
    )
    assert ev.packing.offset == -1024 and (_voxels(ev, priv) == vol).all()
    f = np.random.default_rng(3).uniform(-1, 1, (5, 4, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ev = hevr.encrypt_volume(
            f, tmp_path / "f.zarr", priv, brick=4, layout="packed", value_range=(-1, 1), digits=2, progress=False
        )
    assert ev.packing.offset == -100 and (_voxels(ev, priv) == np.rint(f * 100)).all()


def test_packed_brick_corruption_is_caught(tmp_path, keypair256, volume):
    ev = hevr.encrypt_volume(volume, tmp_path / "c.zarr", keypair256[1], brick=4, layout="packed", progress=False)
    arr = zarr.open_array(str(tmp_path / "c.zarr") + "/scalar", mode="r+")
    rec = arr[0, 0, 0]
    rec[-1] ^= 1
    arr[0, 0, 0] = rec
    with pytest.raises(CorruptStoreError, match="digest mismatch"):
        ev.read_brick((0, 0, 0))


def test_packed_store_keeps_metadata_for_other_readers(packed):
    """A per-voxel reader never mistakes a packed store for its own: the layout is in the checked metadata."""
    d = packed.meta.to_dict()
    stripped = {k: v for k, v in d.items() if k not in ("layout", "checksum")}
    from hevr.store.metadata import metadata_checksum

    stripped["checksum"] = metadata_checksum(stripped)
    meta = VolumeMetadata.from_dict(stripped)
    # without its layout the store's arrays no longer match what the metadata implies
    from hevr.store.layout import array_layout

    assert array_layout(meta)["scalar"][0] != array_layout(packed.meta)["scalar"][0]
    assert dataclasses.replace(meta, packing=packed.packing) == dataclasses.replace(packed.meta)


def test_packed_public_key_path(tmp_path, keypair256, volume):
    """Anyone with the public key can write a packed store; the key holder reads every voxel back."""
    pub, priv = keypair256
    ev = hevr.encrypt_volume(volume, tmp_path / "pub.zarr", pub, brick=4, layout="packed", progress=False)
    assert ev.layout == "packed" and (_voxels(ev, priv) == volume).all()
