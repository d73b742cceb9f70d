"""hevr.store.metadata: VolumeMetadata / ChannelInfo to_dict / from_dict, format version,
and malformed metadata refused with a CorruptStoreError that names what is wrong."""

from __future__ import annotations

import copy
import json

import pytest

from hevr.errors import CorruptStoreError, StoreError
from hevr.store.metadata import FORMAT_NAME, FORMAT_VERSION, ChannelInfo, VolumeMetadata

N = 3233 * 10**70 + 1  # any decimal string will do: metadata never checks primality


def _meta(**kw) -> VolumeMetadata:
    base = dict(
        shape=(5, 7, 9), spacing=(1.0, 2.0, 0.5), brick=(2, 3, 4), n=str(N), fingerprint="ab" * 32,
        ciphertext_bytes=64, dtype="int16", value_range=(-1024.0, 3000.0),
        scalar=ChannelInfo(exponent=0), vector=ChannelInfo(exponent=-3, digits=3, dims=4),
        complete=True, store_id="0123abcd",
    )
    base.update(kw)
    return VolumeMetadata(**base)


def test_format_name_and_version_are_fixed():
    assert FORMAT_NAME == "hevr-encrypted-volume" and FORMAT_VERSION == 1
    d = _meta().to_dict()
    assert d["format"] == "hevr-encrypted-volume" and d["version"] == 1


def test_to_dict_layout():
    d = _meta().to_dict()
    assert d == {
        "format": "hevr-encrypted-volume",
        "version": 1,
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
        "store_id": "0123abcd",
    }


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"vector": None},
        {"scalar": None},
        {"scalar": ChannelInfo(exponent=-2, digits=2), "dtype": "float32", "value_range": (-5.0, 5.0)},
        {"extra": {"source": "tooth.nhdr", "units": ["mm"]}},
        {"complete": False, "store_id": ""},
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
    for k in ("base", "complete", "store_id", "extra", "n_bricks"):
        d.pop(k, None)
    m = VolumeMetadata.from_dict(d)
    assert (m.base, m.complete, m.store_id, m.extra) == (10, False, "", {})


def test_channel_info_round_trip_drops_none():
    assert ChannelInfo(exponent=0).to_dict() == {"exponent": 0}
    assert ChannelInfo(exponent=-3, digits=3, dims=4).to_dict() == {"exponent": -3, "digits": 3, "dims": 4}
    for info in (ChannelInfo(0), ChannelInfo(-2, 2), ChannelInfo(-3, 3, 5)):
        assert ChannelInfo.from_dict(info.to_dict()) == info
    assert ChannelInfo.from_dict({"exponent": "-4"}).exponent == -4


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
        (_set("version", 2), "unsupported format version 2; this hevr reads version 1"),
        (_set("version", "1"), "unsupported format version '1'"),
        (_without("version"), "unsupported format version None"),
        (_set("format", "zarr"), "not an hevr encrypted volume"),
        (_without("format"), "not an hevr encrypted volume"),
        (_without("shape"), r"malformed metadata \(KeyError: 'shape'\)"),
        (_without("public_key.n"), r"malformed metadata \(KeyError: 'n'\)"),
        (_without("public_key.fingerprint"), r"malformed metadata \(KeyError: 'fingerprint'\)"),
        (_without("channels"), r"malformed metadata \(KeyError: 'channels'\)"),
        (_without("channels.vector.exponent"), r"malformed metadata \(KeyError: 'exponent'\)"),
        (_set("shape", ["five", 7, 9]), r"malformed metadata \(ValueError"),
        (_set("spacing", None), r"malformed metadata \(TypeError"),
        (_set("ciphertext_bytes", "sixty-four"), r"malformed metadata \(ValueError"),
        (_set("shape", [5, 7]), "shape, brick and spacing must have 3 entries"),
        (_set("brick", [2, 3, 4, 1]), "shape, brick and spacing must have 3 entries"),
        (_set("spacing", [1.0]), "shape, brick and spacing must have 3 entries"),
        (_set("public_key.n", "0x10"), "public_key.n must be a decimal string"),
        (_set("public_key.n", "-17"), "public_key.n must be a decimal string"),
    ],
)
def test_malformed_metadata_is_named(edit, match):
    d = copy.deepcopy(_meta().to_dict())
    edit(d)
    with pytest.raises(CorruptStoreError, match=match) as info:
        VolumeMetadata.from_dict(d, where="/data/v.zarr")
    assert str(info.value).startswith("/data/v.zarr: ")
    assert isinstance(info.value, StoreError)


@pytest.mark.parametrize("obj", [None, [], "hevr-encrypted-volume", 1])
def test_not_a_dict(obj):
    with pytest.raises(CorruptStoreError, match="^store: not an hevr encrypted volume"):
        VolumeMetadata.from_dict(obj)
