"""TIFF stacks (files written by tifffile) through hevr.read_scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.errors import ParameterError, VolumeFormatError

tifffile = pytest.importorskip("tifffile")

ARR = np.arange(3 * 4 * 5, dtype=np.uint16).reshape(3, 4, 5) * 101  # (z, y, x)


@pytest.mark.parametrize("compression", [None, "zlib"])
def test_imagej_stack_with_spacing(tmp_path: Path, compression: str | None) -> None:
    path = tmp_path / "stack.tif"
    tifffile.imwrite(
        path,
        ARR,
        imagej=True,
        resolution=(1 / 0.5, 1 / 0.25),
        compression=compression,
        metadata={"spacing": 2.0, "unit": "um", "axes": "ZYX"},
    )
    scan = hevr.read_scan(path)
    np.testing.assert_array_equal(scan.volume, ARR)
    assert scan.spacing == pytest.approx((0.5, 0.25, 2.0))
    assert scan.frame is None and scan.origin == (0.0, 0.0, 0.0) and scan.details["unit"] == "um"
    assert isinstance(scan.volume, np.memmap) == (compression is None)  # uncompressed: mapped


def test_plain_pages_and_ome_tiff(tmp_path: Path) -> None:
    tifffile.imwrite(tmp_path / "pages.tiff", ARR, photometric="minisblack")
    vol, spacing = hevr.load_volume(tmp_path / "pages.tiff")
    np.testing.assert_array_equal(vol, ARR)
    assert spacing == (1.0, 1.0, 1.0)
    tifffile.imwrite(
        tmp_path / "v.ome.tif",
        ARR,
        photometric="minisblack",
        metadata={"axes": "ZYX", "PhysicalSizeX": 0.3, "PhysicalSizeY": 0.4, "PhysicalSizeZ": 1.5},
    )
    scan = hevr.read_scan(tmp_path / "v.ome.tif")
    np.testing.assert_array_equal(scan.volume, ARR)
    assert scan.spacing == pytest.approx((0.3, 0.4, 1.5))


def test_time_series_needs_volume(tmp_path: Path) -> None:
    series = np.stack([ARR, ARR + 1])
    tifffile.imwrite(tmp_path / "t.tif", series, imagej=True, metadata={"axes": "TZYX"})
    with pytest.raises(VolumeFormatError, match=r"t\.tif: holds 2 time points .*volume="):
        hevr.load_volume(tmp_path / "t.tif")
    np.testing.assert_array_equal(hevr.load_volume(tmp_path / "t.tif", volume=1)[0], ARR + 1)
    with pytest.raises(ParameterError, match=r"volume: expected an index in \[0, 1\]"):
        hevr.load_volume(tmp_path / "t.tif", volume=2)
    with pytest.raises(ParameterError, match=r"pages\.tif holds a single 3-D volume"):
        tifffile.imwrite(tmp_path / "pages.tif", ARR, photometric="minisblack")
        hevr.load_volume(tmp_path / "pages.tif", volume=0)


@pytest.mark.parametrize("case", ["rgb", "channels", "single-page"])
def test_refused(tmp_path: Path, case: str) -> None:
    path = tmp_path / f"{case}.tif"
    if case == "rgb":
        tifffile.imwrite(path, np.zeros((3, 4, 5, 3), np.uint8), photometric="rgb")
        match = r"rgb\.tif: expected greyscale pages, got 3 samples per pixel.*one scalar per voxel"
    elif case == "channels":
        tifffile.imwrite(path, np.zeros((3, 2, 4, 5), np.uint8), imagej=True, metadata={"axes": "ZCYX"})
        match = r"channels\.tif: expected greyscale pages, got 2 channels"
    else:
        tifffile.imwrite(path, np.zeros((4, 5), np.uint8))
        match = r"single-page\.tif: expected a 3-D stack of pages"
    with pytest.raises(VolumeFormatError, match=match):
        hevr.load_volume(path)


def test_garbage_tiff(tmp_path: Path) -> None:
    (tmp_path / "g.tif").write_bytes(b"II*\0garbage")
    with pytest.raises(VolumeFormatError, match=r"g\.tif: cannot read TIFF file"):
        hevr.load_volume(tmp_path / "g.tif")
