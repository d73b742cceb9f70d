"""NIfTI and FreeSurfer MGH/MGZ through hevr.read_scan: 4-D selection, scaling, RAS+ against
nibabel's own canonical reorientation (files written by nibabel)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.errors import ParameterError, VolumeFormatError

nib = pytest.importorskip("nibabel")

LIA = np.array([[-1.0, 0, 0, 128], [0, 0, 1.0, -128], [0, -1.0, 0, 128], [0, 0, 0, 1]])  # FreeSurfer conformed
LIA_ANISO = LIA @ np.diag([0.5, 1.5, 2.0, 1.0])


def _canonical(img) -> tuple[np.ndarray, tuple, tuple]:
    """nibabel's own RAS+ answer: (volume (z, y, x), spacing, origin)."""
    can = nib.as_closest_canonical(img)
    a = can.affine
    return (np.asarray(can.dataobj).transpose(2, 1, 0), tuple(np.linalg.norm(a[:3, :3], axis=0)), tuple(a[:3, 3]))


@pytest.mark.parametrize("name", ["v.mgz", "v.mgh", "v.nii", "v.nii.gz"])
def test_lia_file_matches_nibabel_canonical(tmp_path: Path, name: str) -> None:
    data = np.arange(4 * 5 * 6, dtype=np.int32).reshape(4, 5, 6)
    cls = nib.MGHImage if name.startswith("v.mg") else nib.Nifti1Image
    nib.save(cls(data, LIA_ANISO), str(tmp_path / name))
    scan = hevr.read_scan(tmp_path / name)
    vol, spacing, origin = _canonical(nib.load(str(tmp_path / name)))
    assert scan.frame == "RAS" and scan.modality is None
    np.testing.assert_array_equal(scan.volume, vol)
    assert scan.spacing == pytest.approx(spacing) and scan.origin == pytest.approx(origin)
    assert scan.volume.dtype == np.int32
    assert scan.details["format"] == cls.__name__


def test_mgz_round_trip(tmp_path: Path) -> None:
    arr = (np.arange(3 * 4 * 5) % 251).astype(np.uint8).reshape(3, 4, 5)  # (z, y, x)
    nib.save(nib.MGHImage(arr.transpose(2, 1, 0), np.diag([0.5, 0.75, 2.0, 1.0])), str(tmp_path / "v.mgz"))
    vol, spacing = hevr.load_volume(tmp_path / "v.mgz")
    np.testing.assert_array_equal(vol, arr)
    assert vol.dtype == np.uint8 and spacing == pytest.approx((0.5, 0.75, 2.0))


def _series(tmp_path: Path, name: str, slope: float = 1.0, inter: float = 0.0) -> np.ndarray:
    data = np.arange(4 * 3 * 2 * 5, dtype=np.int16).reshape(4, 3, 2, 5)  # (x, y, z, t)
    img = nib.Nifti1Image(data, np.diag([1.0, 2.0, 3.0, 1.0]))
    img.header.set_slope_inter(slope, inter)
    nib.save(img, str(tmp_path / name))
    return data


@pytest.mark.parametrize("name", ["f.nii", "f.nii.gz"])
def test_4d_volume_is_picked(tmp_path: Path, name: str) -> None:
    data = _series(tmp_path, name)
    for i in (0, 3, 4):
        scan = hevr.read_scan(tmp_path / name, volume=i)
        np.testing.assert_array_equal(scan.volume, data[..., i].transpose(2, 1, 0))
        assert scan.details["volume"] == i and scan.details["volumes"] == 5
        assert scan.spacing == (1.0, 2.0, 3.0)
    if name == "f.nii":  # unscaled and uncompressed: a view of the memory map, other volumes untouched
        assert isinstance(hevr.load_volume(tmp_path / name, volume=2)[0], np.memmap)


def test_4d_refused_without_volume_and_out_of_range(tmp_path: Path) -> None:
    _series(tmp_path, "f.nii")
    with pytest.raises(VolumeFormatError) as info:
        hevr.load_volume(tmp_path / "f.nii")
    msg = str(info.value)
    assert msg.startswith("f.nii: holds 5 volumes") and "volume=" in msg and "--volume" in msg
    for bad in (5, -1):
        with pytest.raises(ParameterError, match=r"^volume: expected"):
            hevr.read_scan(tmp_path / "f.nii", volume=bad)
    with pytest.raises(ParameterError, match="volume"):
        hevr.read_scan(tmp_path / "f.nii", volume=True)


def test_4d_scaled_stays_integer(tmp_path: Path) -> None:
    data = _series(tmp_path, "s.nii.gz", slope=2.0, inter=-1024.0)
    vol, _ = hevr.load_volume(tmp_path / "s.nii.gz", volume=1)
    assert vol.dtype == np.int16
    np.testing.assert_array_equal(vol, data[..., 1].transpose(2, 1, 0) * 2 - 1024)


def test_volume_refused_for_3d_and_5d_refused(tmp_path: Path) -> None:
    nib.save(nib.Nifti1Image(np.zeros((2, 3, 4), np.uint8), np.eye(4)), str(tmp_path / "three.nii"))
    with pytest.raises(ParameterError, match=r"three\.nii holds a single 3-D volume"):
        hevr.read_scan(tmp_path / "three.nii", volume=0)
    nib.save(nib.Nifti1Image(np.zeros((2, 3, 4, 2, 3), np.uint8), np.eye(4)), str(tmp_path / "five.nii"))
    with pytest.raises(VolumeFormatError, match=r"five\.nii: expected a 3-D volume .* 5-D"):
        hevr.read_scan(tmp_path / "five.nii", volume=0)
    nib.save(nib.Nifti1Image(np.zeros((2, 3, 4, 1, 1), np.uint8), np.eye(4)), str(tmp_path / "ones.nii"))
    assert hevr.read_scan(tmp_path / "ones.nii").volume.shape == (4, 3, 2)  # trailing 1s dropped


def test_rgb_nifti_refused(tmp_path: Path) -> None:
    rgb = np.zeros((2, 3, 4), dtype=[("R", "u1"), ("G", "u1"), ("B", "u1")])
    nib.save(nib.Nifti1Image(rgb, np.eye(4)), str(tmp_path / "rgb.nii"))
    with pytest.raises(VolumeFormatError, match=r"rgb\.nii: expected integer or floating-point voxels"):
        hevr.read_scan(tmp_path / "rgb.nii")


def test_keywords_for_other_formats_refused(tmp_path: Path) -> None:
    nib.save(nib.Nifti1Image(np.zeros((2, 3, 4), np.uint8), np.eye(4)), str(tmp_path / "v.nii"))
    for kwargs in ({"series": "1.2.3"}, {"allow_uneven": True}, {"shape": (4, 3, 2)}):
        with pytest.raises(ParameterError, match=r"v\.nii"):
            hevr.read_scan(tmp_path / "v.nii", **kwargs)
    np.save(tmp_path / "v.npy", np.zeros((2, 2, 2)))
    with pytest.raises(ParameterError, match=r"volume: only applies to 4-D .* v\.npy"):
        hevr.load_volume(tmp_path / "v.npy", volume=0)


def test_a_cifti_file_is_named_not_leaked(tmp_path):
    """nibabel's CIFTI-2 test file: a clear VolumeFormatError, not "'Cifti2Image' object has no
    attribute 'affine'" (issue 29, item 7)."""
    import os

    nib = pytest.importorskip("nibabel")
    path = os.path.join(os.path.dirname(nib.__file__), "tests", "data", "row_major.dconn.nii")
    with pytest.raises(
        hevr.VolumeFormatError,
        match=r"row_major.dconn.nii: expected a NIfTI-1/2 or MGH volume on a "
        r"voxel grid, got a Cifti2 file",
    ) as info:
        hevr.read_scan(path)
    assert "attribute" not in str(info.value)
