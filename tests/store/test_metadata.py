"""hevr.store.metadata: VolumeMetadata / ChannelInfo to_dict / from_dict, format version,
and malformed metadata refused with a CorruptStoreError that names what is wrong."""

from __future__ import annotations

import copy
import json

import pytest

from hevr.errors import CorruptStoreError, StoreError
from hevr.store.metadata import (
    FORMAT_NAME,
    FORMAT_VERSION,
    ChannelInfo,
    VolumeMetadata,
    metadata_checksum,
)

N = 3233 * 10**70 + 1  # any decimal string will do: metadata never checks primality


def _meta(**kw) -> VolumeMetadata:
    base = dict(
        shape=(5, 7, 9),
        spacing=(1.0, 2.0, 0.5),
        brick=(2, 3, 4),
        n=str(N),
        fingerprint="ab" * 32,
        ciphertext_bytes=64,
        dtype="int16",
        value_range=(-1024.0, 3000.0),
        scalar=ChannelInfo(exponent=0),
        vector=ChannelInfo(exponent=-3, digits=3, dims=4),
        complete=True,
        store_id="0123abcd0123abcd",
    )
    base.update(kw)
    names = [k for k in ("scalar", "vector") if base[k] is not None] + ["done"]
    base.setdefault("arrays", {k: "sha256:" + f"{i:x}" * 64 for i, k in enumerate(names)})
    return VolumeMetadata(**base)


def test_format_name_and_version_are_fixed():
    assert FORMAT_NAME == "hevr-encrypted-volume" and FORMAT_VERSION == 2
    d = _meta().to_dict()
    assert d["format"] == "hevr-encrypted-volume" and d["version"] == 2


def test_to_dict_layout():
    d = _meta().to_dict()
    checksum = d.pop("checksum")
    assert checksum == metadata_checksum(d) and checksum.startswith("sha256:") and len(checksum) == 71
    assert d == {
        "format": "hevr-encrypted-volume",
        "version": 2,
        "shape": [5, 7, 9],
        "spacing": [1.0, 2.0, 0.5],
        "brick": [2, 3, 4],
        "public_key": {"n": str(N), "bits": N.bit_length(), "fingerprint": "ab" * 32},
        "ciphertext_bytes": 64,
        "dtype": "int16",
        "value_range": [-1024.0, 3000.0],
        "base": 10,
        "channels": {"scalar": {"exponent": 0}, "vector": {"exponent": -3, "digits": 3, "dims": 4}},
        "n_bricks": 27,
        "complete": True,
        "store_id": "0123abcd0123abcd",
        "arrays": {"scalar": "sha256:" + "0" * 64, "vector": "sha256:" + "1" * 64, "done": "sha256:" + "2" * 64},
    }


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"vector": None},
        {"scalar": None},
        {"scalar": ChannelInfo(exponent=-2, digits=2), "dtype": "float32", "value_range": (-5.0, 5.0)},
        {"extra": {"source": "tooth.nhdr", "units": ["mm"]}},
        {"complete": False},
    ],
    ids=["both", "scalar-only", "vector-only", "float", "extra", "incomplete"],
)
def test_round_trip_through_json(kw):
    meta = _meta(**kw)
    back = VolumeMetadata.from_dict(json.loads(json.dumps(meta.to_dict())))
    assert back == meta
    assert back.to_dict() == meta.to_dict()


def test_grid_and_brick_count_are_ceil_divisions():
    assert _meta().grid == (3, 3, 3) and _meta().n_bricks == 27
    m = _meta(shape=(4, 6, 8), brick=(4, 3, 3))
    assert m.grid == (1, 2, 3) and m.n_bricks == 6
    assert m.to_dict()["n_bricks"] == 6


def test_defaults_when_optional_fields_are_absent():
    d = _meta().to_dict()
    for k in ("base", "complete", "extra", "n_bricks"):
        d.pop(k, None)
    d["checksum"] = metadata_checksum(d)
    m = VolumeMetadata.from_dict(d)
    assert (m.base, m.complete, m.extra) == (10, False, {})


def test_channel_info_round_trip_drops_none():
    assert ChannelInfo(exponent=0).to_dict() == {"exponent": 0}
    assert ChannelInfo(exponent=-3, digits=3, dims=4).to_dict() == {"exponent": -3, "digits": 3, "dims": 4}
    for info in (ChannelInfo(0), ChannelInfo(-2, 2), ChannelInfo(-3, 3, 5)):
        assert ChannelInfo.from_dict(info.to_dict()) == info
    with pytest.raises(CorruptStoreError, match="channels.exponent: expected an integer"):
        ChannelInfo.from_dict({"exponent": "-4"})


def test_no_secret_fields():
    """Only the public modulus: the dict has no p, q, lambda or mu anywhere."""
    text = json.dumps(_meta().to_dict())
    for word in ('"p"', '"q"', "lambda", '"mu"', "private"):
        assert word not in text


# -- refused input -----------------------------------------------------------------------------


def _without(path: str):
    def edit(d):
        *parents, last = path.split(".")
        for p in parents:
            d = d[p]
        del d[last]

    return edit


def _set(path: str, value):
    def edit(d):
        *parents, last = path.split(".")
        for p in parents:
            d = d[p]
        d[last] = value

    return edit


@pytest.mark.parametrize(
    "edit, match",
    [
        (_set("version", 3), "unsupported format version 3; this hevr reads version 2"),
        (_set("version", "2"), "unsupported format version '2'"),
        (_set("version", True), "unsupported format version True"),
        (_without("version"), "unsupported format version None"),
        (_set("version", 1), r"format version 1 has no integrity digests.*hevr upgrade-store /data/v.zarr NEW.zarr"),
        (_set("format", "zarr"), "not an hevr encrypted volume"),
        (_without("format"), "not an hevr encrypted volume"),
        (_without("shape"), r"malformed metadata \(missing field 'shape'\)"),
        (_without("public_key.n"), r"malformed metadata \(missing field 'public_key.n'\)"),
        (_without("public_key.fingerprint"), r"missing field 'public_key.fingerprint'"),
        (_without("channels"), r"missing field 'channels'"),
        (_without("channels.vector.exponent"), r"channels.vector: expected an object with 'exponent'"),
        (_set("shape", ["five", 7, 9]), r"shape: expected an integer in \[1, ∞\], got 'five'"),
        (_set("shape", [5.0, 7, 9]), r"shape: expected an integer"),
        (_set("shape", [True, 7, 9]), r"shape: expected an integer"),
        (_set("spacing", None), r"spacing: expected a list of 3 entries"),
        (_set("spacing", [1.0, -2.0, 1.0]), r"spacing: expected a positive finite number, got -2.0"),
        (_set("ciphertext_bytes", "sixty-four"), r"ciphertext_bytes: expected an integer"),
        (_set("shape", [5, 7]), "shape: expected a list of 3 entries"),
        (_set("brick", [2, 3, 4, 1]), "brick: expected a list of 3 entries"),
        (_set("brick", [2, 0, 4]), r"brick: expected an integer in \[1, ∞\], got 0"),
        (_set("brick", [2, -3, 4]), r"brick: expected an integer in \[1, ∞\], got -3"),
        (_set("spacing", [1.0]), "spacing: expected a list of 3 entries"),
        (_set("public_key.n", "0x10"), "public_key.n must be a decimal string"),
        (_set("public_key.n", "-17"), "public_key.n must be a decimal string"),
        (_set("public_key.n", "١٢٣"), "public_key.n must be a decimal string"),
        (_set("public_key.n", "9" * 6000), "public_key.n must be a decimal string"),
        (_set("public_key.n", "9" * 4301), "public_key.n must be a decimal string"),  # past int()'s limit
        (_set("public_key.bits", 7), r"public_key.bits: expected \d+ \(the bit length of n\)"),
        (_set("public_key.fingerprint", "AB" * 32), "fingerprint: expected 64 lower-case hex digits"),
        (_set("dtype", "complex128"), "dtype: expected one of bool, int8"),
        (_set("value_range", [3000.0, -1024.0]), r"value_range: expected lo < hi"),
        (_set("value_range", [0.0, float("inf")]), r"value_range: expected a finite number"),
        (_set("complete", "yes"), r"complete: expected true or false, got 'yes'"),
        (_set("complete", 1), r"complete: expected true or false, got 1"),
        (_set("store_id", ""), r"store_id: expected 16 lower-case hex digits"),
        (_set("base", 2), r"base: expected 10, got 2"),
        (_set("n_bricks", 26), r"n_bricks: expected 27"),
        (_set("channels", {}), r"channels: expected an object with 'scalar' and/or 'vector'"),
        (_set("channels.scalar", {"exponent": -2, "digits": 3}), r"channels.scalar.exponent: expected -digits = -3"),
        (_set("channels.vector.dims", 1), r"channels.vector.dims: expected an integer in \[2, 64\]"),
        (_set("extra", []), r"extra: expected an object"),
        (_without("arrays"), r"arrays: expected a 'sha256:…' digest for each of \['done', 'scalar', 'vector'\]"),
        (_without("arrays.done"), r"arrays: expected a 'sha256:…' digest"),
        (_set("arrays.scalar", "sha256:xyz"), r"arrays: expected a 'sha256:…' digest"),
    ],
)
def test_malformed_metadata_is_named(edit, match):
    """Each field is validated (the checksum recomputed, as a crafted store would)."""
    d = copy.deepcopy(_meta().to_dict())
    edit(d)
    d["checksum"] = metadata_checksum(d)
    with pytest.raises(CorruptStoreError, match=match) as info:
        VolumeMetadata.from_dict(d, where="/data/v.zarr")
    assert str(info.value).startswith("/data/v.zarr: ")
    assert isinstance(info.value, StoreError)


@pytest.mark.parametrize(
    "edit",
    [
        _set("shape", [5, 7, 8]),
        _set("complete", False),
        _set("store_id", "f" * 16),
        _set("value_range", [-1024.0, 3001.0]),
        _set("public_key.n", str(N + 2)),
    ],
)
def test_any_edit_without_the_checksum_is_detected(edit):
    d = copy.deepcopy(_meta().to_dict())
    edit(d)
    with pytest.raises(CorruptStoreError, match="metadata checksum mismatch"):
        VolumeMetadata.from_dict(d)
    del d["checksum"]
    with pytest.raises(CorruptStoreError, match="metadata checksum missing"):
        VolumeMetadata.from_dict(d)


def test_version_1_is_read_only_for_the_upgrade():
    d = _meta(version=1).to_dict()
    assert "checksum" not in d
    m = VolumeMetadata.from_dict(d, accept_v1=True)
    assert m.version == 1 and m.shape == (5, 7, 9)


@pytest.mark.parametrize("obj", [None, [], "hevr-encrypted-volume", 1])
def test_not_a_dict(obj):
    with pytest.raises(CorruptStoreError, match="^store: not an hevr encrypted volume"):
        VolumeMetadata.from_dict(obj)


def test_patient_frame_round_trip_and_strict_parsing():
    meta = _meta(patient={"frame": "RAS", "origin": (-50.5, -46.0, -80.5)})
    d = json.loads(json.dumps(meta.to_dict()))
    assert d["patient"] == {"frame": "RAS", "origin": [-50.5, -46.0, -80.5]}
    assert VolumeMetadata.from_dict(d) == meta
    assert "patient" not in _meta().to_dict() and VolumeMetadata.from_dict(_meta().to_dict()).patient == {}
    for bad in (
        {"frame": "LPS", "origin": [0, 0, 0]},
        {"frame": "RAS"},
        {"frame": "RAS", "origin": [0, 0]},
        {"frame": "RAS", "origin": [0, "1", 0]},
        {"frame": "RAS", "origin": [0, float("nan"), 0]},
        {"frame": "RAS", "origin": [0, 0, 0], "modality": "CT"},
        [],
    ):
        d = meta.to_dict()
        d["patient"] = bad
        d.pop("checksum")
        d["checksum"] = metadata_checksum(d)
        with pytest.raises(CorruptStoreError, match="patient"):
            VolumeMetadata.from_dict(d)
