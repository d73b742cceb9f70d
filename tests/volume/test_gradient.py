"""The gradient channel g·e(d) (hevr.volume.gradient, encrypt_volume(..., gradient=True)): the stored
channel decrypts to the quantised definition computed here independently with numpy (whole-volume
central differences in world units), across bricks, dask chunks, flat axes and a cluster; its
metadata, layout, digests, pyramid, residency and resume; the normaliser is never stored; bad input
is named."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import dask
import dask.array as da
import numpy as np
import pytest
import zarr

import hevr
from hevr.store import writer as store_mod
from hevr.store.metadata import (
    ChannelInfo,
    VolumeMetadata,
    metadata_checksum,
    ome_attribute,
)
from hevr.store.pyramid import LEVEL_FACTOR, build_pyramid
from hevr.volume.density import encode_density
from hevr.volume.gradient import gradient_encoding, gradient_magnitude

RND_SPACING = (0.7, 1.3, 2.0)  # world order (sx, sy, sz): anisotropic


def _reference(vol, spacing, value_range, k, digits=3):
    """(k, nz, ny, nx) mantissas round(g·e(d)·10^digits), written from the definition, not from hevr.volume.gradient."""
    lo, hi = value_range
    d = np.clip((vol.astype(np.float64) - lo) / (hi - lo), 0.0, 1.0)
    sx, sy, sz = spacing
    parts = [np.gradient(d, s, axis=a) if d.shape[a] > 1 else np.zeros_like(d) for a, s in enumerate((sz, sy, sx))]
    m = np.sqrt(sum(p * p for p in parts))
    g = m / m.max() if m.max() > 0 else np.zeros_like(m)
    q = np.rint(g[..., None] * encode_density(d, k) * 10.0**digits).astype(np.int64)
    return np.moveaxis(q, -1, 0)


def _decrypt(ev, priv, channel="gradient"):
    k = ev.meta.components(channel)
    out = np.zeros((k,) + ev.shape, dtype=np.int64)
    for idx in ev.brick_indices():
        sl = ev.brick_slices(idx)
        for j, cts in enumerate(ev.read_brick(idx, channel)):
            out[(j,) + sl] = np.array(priv.decrypt_array(cts), dtype=object).reshape(ev.brick_shape(idx))
    return out


def _rnd():
    return np.random.default_rng(11).integers(0, 256, (7, 9, 8)).astype(np.uint8)


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256):
    _, priv = keypair256
    d = tmp_path_factory.mktemp("gradient")
    ph = hevr.phantom(10)
    rnd = _rnd()
    return {
        "phantom": (
            hevr.encrypt_volume(ph, d / "ph.zarr", priv, brick=4, vector_dims=4, gradient=True, progress=False),
            ph,
            (1.0, 1.0, 1.0),
        ),
        "random": (
            hevr.encrypt_volume(
                rnd, d / "rnd.zarr", priv, brick=4, vector_dims=3, gradient=True, spacing=RND_SPACING, progress=False
            ),
            rnd,
            RND_SPACING,
        ),
    }


@pytest.mark.parametrize("name", ["phantom", "random"])
def test_the_stored_channel_is_the_quantised_definition(stores, keypair256, name):
    ev, vol, spacing = stores[name]
    priv = keypair256[1]
    ref = _reference(vol, spacing, (0, 255), ev.vector_dims)
    assert np.array_equal(_decrypt(ev, priv), ref)  # brick halos give exactly the whole volume's differences
    assert ref.max() > 0 and (ref == 0).any()
    assert np.array_equal(
        _decrypt(ev, priv, "vector"),
        np.moveaxis(np.rint(encode_density(np.clip(vol / 255.0, 0, 1), ev.vector_dims) * 1000).astype(np.int64), -1, 0),
    )  # the vector channel unchanged
    # the float field the writer quantises is hevr.volume.gradient's, which render_plain renders
    G = gradient_encoding(vol, spacing, (0, 255), ev.vector_dims)
    assert np.array_equal(np.moveaxis(np.rint(G * 1000).astype(np.int64), -1, 0), ref)


def test_metadata_layout_and_digests(stores, keypair256):
    ev, _, _ = stores["random"]
    meta = ev.meta
    assert meta.channel_names == ("scalar", "vector", "gradient") and ev.has_gradient
    assert meta.gradient == meta.vector and meta.components("gradient") == 3
    doc = json.loads((Path(ev.path) / "zarr.json").read_text())["attributes"]["hevr"]
    assert doc["channels"]["gradient"] == {"exponent": -3, "digits": 3, "dims": 3}
    assert set(doc["arrays"]) == {"scalar", "vector", "gradient", "done"}
    assert "gradient[3]" in repr(ev)
    assert ev.read_brick_bytes((1, 2, 1), channel="gradient").shape == (3, 3, 1, 4, ev.meta.ciphertext_bytes)
    g = zarr.open_group(ev.path, mode="r")
    assert g["gradient"].shape == (3, 7, 9, 8, meta.ciphertext_bytes) and g["done"].shape == (2, 3, 2, 3, 32)
    hevr.open_volume(ev.path, verify="full")  # every digest and ciphertext of the three channels
    assert VolumeMetadata.from_dict(meta.to_dict()) == meta
    chunk = Path(ev.path) / "gradient" / "c" / "0" / "0" / "0" / "0" / "0"  # component axis, brick, W axis
    cipher = 3 * 4**3 * meta.ciphertext_bytes  # one chunk holds all 3 components of a brick
    assert cipher < chunk.stat().st_size <= cipher + 24  # + the zstd frame's headers and the crc32c


def test_corrupt_gradient_metadata_is_named():
    base = VolumeMetadata(
        shape=(2, 2, 2),
        spacing=(1.0, 1.0, 1.0),
        brick=(2, 2, 2),
        n="3233",
        fingerprint="ab" * 32,
        ciphertext_bytes=3,
        dtype="uint8",
        value_range=(0.0, 255.0),
        scalar=None,
        vector=ChannelInfo(-3, 3, 2),
        gradient=ChannelInfo(-3, 3, 2),
        complete=True,
        store_id="0123456789abcdef",
        arrays={n: "sha256:" + "0" * 64 for n in ("vector", "gradient", "done")},
    )
    assert VolumeMetadata.from_dict(base.to_dict()) == base
    for change, match in (
        (lambda d: d["channels"]["gradient"].update(dims=3), "channels.gradient: expected the same"),
        (
            lambda d: d["channels"].pop("vector") and d["arrays"].pop("vector"),
            "channels: expected an object with 'scalar' and/or 'vector'",
        ),
    ):
        d = base.to_dict()
        change(d)
        d["checksum"] = metadata_checksum(d)
        with pytest.raises(hevr.CorruptStoreError, match=match):
            VolumeMetadata.from_dict(d)


def test_the_normaliser_is_never_stored(stores):
    ev, vol, spacing = stores["random"]
    m = gradient_magnitude(vol / 255.0, spacing)
    top = float(m.max())
    text = "".join(f.read_text(errors="ignore") for f in Path(ev.path).rglob("zarr.json"))
    for form in (repr(top), f"{top:.6g}", f"{top:.4f}", f"{1 / top:.6g}"):
        assert form not in text


def test_dask_input_flat_axes_floats_and_a_cluster(tmp_path, keypair256, cluster):
    pub, priv = keypair256
    rnd = _rnd()
    darr = da.from_array(rnd, chunks=(3, 5, 2))  # chunks unrelated to the bricks
    ev = hevr.encrypt_volume(
        darr,
        tmp_path / "d.zarr",
        pub,
        brick=(2, 4, 3),
        vector_dims=3,
        gradient=True,
        spacing=RND_SPACING,
        scalar=False,
        progress=False,
        client=cluster,
    )
    assert ev.meta.channel_names == ("vector", "gradient")
    assert np.array_equal(_decrypt(ev, priv), _reference(rnd, RND_SPACING, (0, 255), 3))
    flat = rnd[:1, :, :5]  # one voxel along z: that axis contributes nothing
    ev = hevr.encrypt_volume(
        flat, tmp_path / "f.zarr", priv, brick=(1, 4, 2), vector_dims=2, gradient=True, vector_digits=4, progress=False
    )
    assert np.array_equal(_decrypt(ev, priv), _reference(flat, (1, 1, 1), (0, 255), 2, digits=4))
    flt = (np.random.default_rng(3).random((5, 6, 4)) * 4 - 1).astype(np.float32)
    ev = hevr.encrypt_volume(
        flt, tmp_path / "x.zarr", priv, brick=3, vector_dims=2, gradient=True, value_range=(-1.0, 3.0), progress=False
    )
    assert np.array_equal(_decrypt(ev, priv), _reference(flt, (1, 1, 1), (-1.0, 3.0), 2))
    const = np.full((4, 4, 4), 9, np.uint8)  # max |∇d| = 0: g = 0 everywhere
    ev = hevr.encrypt_volume(const, tmp_path / "c.zarr", priv, brick=2, vector_dims=2, gradient=True, progress=False)
    assert not _decrypt(ev, priv).any()


def test_pyramid_residency_and_ome(tmp_path, keypair256):
    _, priv = keypair256
    vol = hevr.phantom(10)
    ev = build_pyramid(
        hevr.encrypt_volume(
            vol, tmp_path / "p.zarr", priv, brick=4, vector_dims=2, gradient=True, scalar=False, progress=False
        ),
        1,
        progress=False,
    )
    lv = ev.at_level(1)
    assert lv.meta.gradient == lv.meta.vector and lv.meta.gradient.exponent == -6
    below = _decrypt(ev, priv)
    kids = np.pad(below, [(0, 0)] + [(0, s % 2) for s in below.shape[1:]], mode="edge")
    k, z, y, x = kids.shape
    want = LEVEL_FACTOR * kids.reshape(k, z // 2, 2, y // 2, 2, x // 2, 2).sum(axis=(2, 4, 6))
    assert np.array_equal(_decrypt(lv, priv), want)  # 125·Σ of the 8 children, like any channel
    ome = ome_attribute(ev.meta)["multiscales"]
    assert [m["name"] for m in ome] == ["vector", "gradient"] and ome[1]["axes"][0]["name"] == "component"
    assert ome[1]["datasets"][1]["path"] == "levels/1/gradient"
    res = ev.persist(channels="gradient")
    assert res.resident.channels == ("gradient",)
    cam = hevr.Camera.orbit(ev, width=6, height=6)
    a = hevr.render(res, cam, mode="emphasize", density=0.5, gradient=True, progress=False)
    assert a.stats["resident"]
    with pytest.raises(hevr.ParameterError, match="channels"):
        ev.persist(channels="rgb")


def test_resume_of_an_interrupted_gradient_encryption(tmp_path, keypair256, monkeypatch):
    _, priv = keypair256
    vol, path = _rnd(), tmp_path / "r.zarr"
    real, calls = store_mod._encrypt_brick, []

    def flaky(*args, **kw):
        if len(calls) >= 5:
            raise RuntimeError("worker died")
        calls.append(args[2])
        return real(*args, **kw)

    monkeypatch.setattr(store_mod, "_encrypt_brick", flaky)
    kw = dict(brick=4, vector_dims=2, gradient=True, spacing=RND_SPACING, progress=False)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError, match="worker died"):
        hevr.encrypt_volume(vol, path, priv, **kw)
    monkeypatch.undo()
    with pytest.raises(hevr.ParameterError, match="gradient: resume needs the same gradient"):
        hevr.encrypt_volume(vol, path, priv, **dict(kw, gradient=False), resume=True)
    ev = hevr.encrypt_volume(vol, path, priv, **kw, resume=True)  # max |∇d| recomputed from the whole volume
    assert np.array_equal(_decrypt(ev, priv), _reference(vol, RND_SPACING, (0, 255), 2))
    chunk = Path(ev.path) / "gradient" / "c" / "0" / "1" / "1" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[100] ^= 1
    chunk.write_bytes(bytes(data))
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 0\) of channel 'gradient'"):
        ev.read_brick((1, 1, 0), "gradient")


def test_bad_input_is_named(tmp_path, keypair256, stores):
    pub, _ = keypair256
    vol = _rnd()
    with pytest.raises(hevr.ParameterError, match=r"gradient: expected vector_dims=k as well, got vector_dims=None"):
        hevr.encrypt_volume(vol, tmp_path / "a.zarr", pub, gradient=True, progress=False)
    with pytest.raises(hevr.ParameterError, match="gradient: expected True or False, got 'yes'"):
        hevr.encrypt_volume(vol, tmp_path / "a.zarr", pub, vector_dims=2, gradient="yes", progress=False)
    assert not (tmp_path / "a.zarr").exists()
    ev = dataclasses.replace(stores["random"][0].meta, gradient=None)
    with pytest.raises(hevr.ParameterError, match="channel: this store has no gradient channel"):
        hevr.EncryptedVolume(stores["random"][0].path, ev).read_brick((0, 0, 0), "gradient")
