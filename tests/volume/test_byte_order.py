"""Issue 24 item 5: big-endian inputs (``>i2``, ``>f8``, as some NRRD and raw files give) are
encrypted as their values, in memory and memory-mapped (swapped inside each task, never read
whole), with byte-order independent resume digests; ``hevr encrypt`` of a big-endian file works."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import hevr
import hevr.store.writer as writer
from hevr.cli.main import main
from hevr.rendering.encrypted import error_bound
from hevr.store.journal import plain_digest
from hevr.volume.mapped import MappedFile, file_backed, task_array

SHAPE = (6, 7, 5)
SPACING = (1.0, 1.5, 0.75)


def _ints() -> np.ndarray:
    return np.random.default_rng(5).integers(-900, 900, SHAPE).astype(np.int16)


def _floats() -> np.ndarray:
    return np.random.default_rng(6).uniform(-3.0, 7.0, SHAPE)


def _render(ev, priv, mode="xray", **kw):
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=9, height=8)
    return cam, hevr.render(ev, cam, mode=mode, progress=False, **kw).decrypt(priv)


@pytest.mark.parametrize(
    "make, kw", [(_ints, {}), (_floats, {"value_range": (-3, 7), "digits": 4})], ids=["int16", "float64"]
)
def test_big_endian_arrays_encrypt_their_values(tmp_path, keypair256, make, kw):
    priv = keypair256[1]
    native = make()
    big = native.astype(native.dtype.newbyteorder(">"))
    assert not big.dtype.isnative and np.array_equal(big, native)
    stores = {}
    for name, vol in [("native", native), ("big", big), ("little", native.astype(native.dtype.newbyteorder("<")))]:
        stores[name] = hevr.encrypt_volume(
            vol, tmp_path / f"{name}.zarr", priv, brick=3, spacing=SPACING, vector_dims=3, progress=False, **kw
        )
        assert stores[name].dtype == native.dtype.name  # the store records the values' type, not a byte order
    for mode, extra in [("xray", {}), ("emphasize", {"density": 0.4})]:
        cam, got = _render(stores["big"], priv, mode, **extra)
        ref = hevr.render_plain(
            native, cam, mode=mode, spacing=SPACING, vector_dims=3, value_range=stores["native"].value_range, **extra
        )
        assert np.all(np.abs(got - ref) <= error_bound(stores["big"], cam, mode, **extra))
        assert np.count_nonzero(ref) > 10
        for other in ("native", "little"):
            assert np.array_equal(_render(stores[other], priv, mode, **extra)[1], got)


def test_a_big_endian_memory_map_is_read_inside_the_tasks(tmp_path, keypair256):
    priv = keypair256[1]
    native = _ints()
    path = tmp_path / "v.raw"
    native.astype(">i2").tofile(path)
    mm = np.memmap(path, ">i2", "r", shape=SHAPE)[:, ::-1]  # a flipped view, as the loaders give
    src = file_backed(mm)
    assert isinstance(src, MappedFile) and src.dtype == np.int16 and src.dtype.isnative
    back = pickle.loads(pickle.dumps(src))
    assert back.file_dtype == np.dtype(">i2") and len(pickle.dumps(src)) < 400
    assert np.array_equal(back[1:3, ::2], native[:, ::-1][1:3, ::2]) and back[...].dtype.isnative
    darr = task_array(mm, (3, 3, 3), "t")
    assert darr.dtype == np.int16 and np.array_equal(darr.compute(), native[:, ::-1])
    ev = hevr.encrypt_volume(mm, tmp_path / "m.zarr", priv, brick=3, progress=False)
    ref = hevr.encrypt_volume(np.ascontiguousarray(native[:, ::-1]), tmp_path / "r.zarr", priv, brick=3, progress=False)
    assert np.array_equal(_render(ev, priv)[1], _render(ref, priv)[1])


def test_resume_digests_do_not_depend_on_byte_order(tmp_path, keypair256, monkeypatch):
    native = _ints()
    for dt in (">i2", "<i2", "=i2"):
        assert plain_digest(native.astype(dt)) == plain_digest(native)
    assert plain_digest(native) != plain_digest(native.astype(np.uint16))  # the type still counts
    # an interrupted run on the little-endian volume resumes from the big-endian one
    calls = {"n": 0}
    real = writer._encrypt_brick

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RuntimeError("worker lost")
        return real(*args, **kwargs)

    monkeypatch.setattr(writer, "_encrypt_brick", flaky)
    with pytest.raises(RuntimeError, match="worker lost"):
        hevr.encrypt_volume(
            native.astype("<i2"), tmp_path / "v.zarr", keypair256[1], brick=3, progress=False, client=None
        )
    monkeypatch.setattr(writer, "_encrypt_brick", real)
    ev = hevr.encrypt_volume(
        native.astype(">i2"), tmp_path / "v.zarr", keypair256[1], brick=3, resume=True, progress=False
    )
    assert np.array_equal(
        hevr.render_plain(native, hevr.Camera.orbit(ev, width=5, height=5)),
        hevr.render_plain(native.astype(">i2"), hevr.Camera.orbit(ev, width=5, height=5)),
    )
    ref = hevr.encrypt_volume(native, tmp_path / "r.zarr", keypair256[1], brick=3, progress=False)
    assert np.array_equal(_render(ev, keypair256[1])[1], _render(ref, keypair256[1])[1])


@pytest.mark.parametrize("name", ["v.nrrd", "v.nhdr"])
def test_hevr_encrypt_of_a_big_endian_file(tmp_path, keypair256, name, capsys):
    pub, priv = keypair256
    priv.save(tmp_path / "key.json")
    native = _ints()
    path = hevr.save_volume(tmp_path / name, native, SPACING, byte_order="big")
    assert "endian: big" in (
        path.read_text(errors="replace") if name.endswith("nhdr") else path.read_bytes().split(b"\n\n")[0].decode()
    )
    code = main(
        [
            "encrypt",
            str(path),
            "--key",
            str(tmp_path / "key.json"),
            "--out",
            str(tmp_path / "v.zarr"),
            "--brick",
            "3",
            "-q",
        ]
    )
    assert code == 0, capsys.readouterr().err
    ev = hevr.open_volume(tmp_path / "v.zarr")
    ref = hevr.encrypt_volume(native, tmp_path / "r.zarr", priv, brick=3, spacing=SPACING, progress=False)
    assert ev.dtype == "int16" and np.array_equal(_render(ev, priv)[1], _render(ref, priv)[1])
