"""Plaintext Zarr arrays and OME-Zarr images (written by zarr itself) through hevr.read_scan;
encrypted hevr stores are refused."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import zarr

import hevr
from hevr.errors import InsecureKeyWarning, ParameterError, VolumeFormatError

ARR = np.arange(3 * 4 * 5, dtype=np.int16).reshape(3, 4, 5) - 30  # (z, y, x)


@pytest.mark.parametrize("zarr_format", [2, 3])
def test_plain_array(tmp_path: Path, zarr_format: int) -> None:
    path = tmp_path / "a.zarr"
    z = zarr.create_array(str(path), shape=ARR.shape, chunks=(2, 2, 2), dtype=ARR.dtype, zarr_format=zarr_format)
    z[...] = ARR
    scan = hevr.read_scan(path)
    assert type(scan.volume) is np.ndarray  # read into memory
    np.testing.assert_array_equal(scan.volume, ARR)
    assert scan.spacing == (1.0, 1.0, 1.0) and scan.frame is None and scan.details["zarr_format"] == zarr_format
    assert hevr.load_volume(path, spacing=(2, 3, 4))[1] == (2.0, 3.0, 4.0)
    with pytest.raises(ParameterError, match=r"a\.zarr holds a single 3-D volume"):
        hevr.load_volume(path, volume=0)


def _ome(
    path: Path,
    data: np.ndarray,
    axes: list[dict],
    scale: list[float],
    zarr_format: int = 3,
    translation: list[float] | None = None,
) -> Path:
    group = zarr.open_group(str(path), mode="w", zarr_format=zarr_format)
    for level, factor in (("0", 1), ("1", 2)):
        a = group.create_array(
            level,
            shape=tuple(s if i < len(data.shape) - 3 else -(-s // factor) for i, s in enumerate(data.shape)),
            dtype=data.dtype,
        )
        if level == "0":
            a[...] = data
    transforms: list[dict] = [{"type": "scale", "scale": scale}]
    if translation:
        transforms.append({"type": "translation", "translation": translation})
    ms = {
        "axes": axes,
        "datasets": [
            {"path": "0", "coordinateTransformations": transforms},
            {"path": "1", "coordinateTransformations": [{"type": "scale", "scale": scale}]},
        ],
    }
    if zarr_format == 2:
        group.attrs["multiscales"] = [{"version": "0.4", **ms}]
    else:
        group.attrs["ome"] = {"version": "0.5", "multiscales": [ms]}
    return path


ZYX = [{"name": n, "type": "space", "unit": "micrometer"} for n in "zyx"]


@pytest.mark.parametrize("zarr_format", [2, 3], ids=["ngff-0.4", "ngff-0.5"])
def test_ome_zarr(tmp_path: Path, zarr_format: int) -> None:
    path = _ome(tmp_path / "img.ome.zarr", ARR, ZYX, [2.0, 0.5, 0.25], zarr_format, translation=[7.0, 8.0, 9.0])
    scan = hevr.read_scan(path)
    np.testing.assert_array_equal(scan.volume, ARR)  # level 0, the full resolution
    assert scan.spacing == (0.25, 0.5, 2.0) and scan.origin == (9.0, 8.0, 7.0)
    assert scan.details["unit"] == "micrometer" and scan.frame is None


def test_ome_zarr_time_and_channel(tmp_path: Path) -> None:
    series = np.stack([ARR, ARR * 2])[:, None]  # (t, c=1, z, y, x)
    axes = [{"name": "t", "type": "time"}, {"name": "c", "type": "channel"}, *ZYX]
    path = _ome(tmp_path / "t.zarr", series, axes, [1.0, 1.0, 3.0, 2.0, 1.0])
    with pytest.raises(VolumeFormatError, match=r"t\.zarr: holds 2 time points along its axis 't'.*volume="):
        hevr.load_volume(path)
    vol, spacing = hevr.load_volume(path, volume=1)
    np.testing.assert_array_equal(vol, ARR * 2)
    assert spacing == (1.0, 2.0, 3.0)
    channels = _ome(
        tmp_path / "c.zarr", np.stack([ARR, ARR]), [{"name": "c", "type": "channel"}, *ZYX], [1.0, 1.0, 1.0, 1.0]
    )
    with pytest.raises(VolumeFormatError, match=r"c\.zarr: expected one channel, got 2"):
        hevr.load_volume(channels)


def test_ome_zarr_axes_in_xyz_order(tmp_path: Path) -> None:
    path = _ome(tmp_path / "xyz.zarr", ARR.transpose(2, 1, 0).copy(), ZYX[::-1], [0.25, 0.5, 2.0])
    scan = hevr.read_scan(path)
    np.testing.assert_array_equal(scan.volume, ARR)
    assert scan.spacing == (0.25, 0.5, 2.0)


def test_group_without_multiscales_refused(tmp_path: Path) -> None:
    zarr.open_group(str(tmp_path / "g.zarr"), mode="w").attrs["note"] = "nothing here"
    with pytest.raises(VolumeFormatError, match=r"g\.zarr: a Zarr group without OME-NGFF 'multiscales'"):
        hevr.load_volume(tmp_path / "g.zarr")
    z = zarr.create_array(str(tmp_path / "two.zarr"), shape=(4, 5), dtype="u1")
    z[...] = 1
    with pytest.raises(VolumeFormatError, match=r"two\.zarr: expected a 3-D Zarr array"):
        hevr.load_volume(tmp_path / "two.zarr")


def test_encrypted_hevr_store_refused(tmp_path: Path, keypair256) -> None:
    pub = keypair256[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        hevr.encrypt_volume(np.zeros((2, 2, 2), np.uint8), tmp_path / "e.zarr", pub, brick=2)
    with pytest.raises(VolumeFormatError, match=r"e\.zarr: this is an encrypted hevr store, not a plaintext volume"):
        hevr.load_volume(tmp_path / "e.zarr")
    inner = [p.parent for p in (tmp_path / "e.zarr").rglob("zarr.json") if p.parent != tmp_path / "e.zarr"]
    assert inner
    with pytest.raises(VolumeFormatError, match=r"this is an encrypted hevr store \(inside e\.zarr\)"):
        hevr.load_volume(inner[0])
