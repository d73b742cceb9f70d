"""One patient frame (RAS+) for every reader: the same phantom stored in different voxel orders
(NIfTI written by nibabel, NRRD written by pynrrd) loads to the same array, spacing and origin."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.errors import ParameterError, VolumeFormatError

nib = pytest.importorskip("nibabel")
nrrd = pytest.importorskip("nrrd")

SHAPE = (5, 6, 7)  # (nz, ny, nx): no two axes alike
SPACING = (0.5, 1.25, 2.0)  # (sx, sy, sz)
ORIGIN = (10.0, -20.0, 30.0)  # RAS+ mm of voxel (0, 0, 0)


def _phantom() -> np.ndarray:
    """Distinct values everywhere and a bright blob at the patient's right-anterior-superior corner."""
    vol = np.arange(np.prod(SHAPE), dtype=np.int16).reshape(SHAPE)
    vol[-2:, -2:, -2:] = 1000  # high z (superior), high y (anterior), high x (right)
    return vol


def _stored(perm: tuple[int, ...], flips: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The phantom as a file stores it when its voxel axis a runs along world axis perm[a]
    (reversed where flips[a]): the (i, j, k)-indexed data and the voxel -> RAS+ affine."""
    xyz = _phantom().transpose(2, 1, 0)  # indexed [x, y, z]
    data = xyz.transpose(perm)
    for a, flip in enumerate(flips):
        if flip:
            data = np.flip(data, axis=a)
    n_xyz = SHAPE[::-1]
    affine = np.zeros((4, 4))
    affine[3, 3] = 1.0
    for a, (w, flip) in enumerate(zip(perm, flips)):
        affine[w, a] = -SPACING[w] if flip else SPACING[w]
        affine[w, 3] = ORIGIN[w] + ((n_xyz[w] - 1) * SPACING[w] if flip else 0.0)
    return np.ascontiguousarray(data), affine


def _save_nifti(path: Path, data: np.ndarray, affine: np.ndarray) -> Path:
    nib.save(nib.Nifti1Image(data, affine), str(path))
    return path


def _save_nrrd(path: Path, data: np.ndarray, affine_ras: np.ndarray, space: str) -> Path:
    signs = {
        "right-anterior-superior": (1, 1, 1),
        "left-anterior-superior": (-1, 1, 1),
        "left-posterior-superior": (-1, -1, 1),
    }[space]
    a = np.diag([*signs, 1.0]) @ affine_ras  # RAS+ -> the file's space
    header = {
        "space": space,
        "space directions": a[:3, :3].T,
        "space origin": a[:3, 3],
        "encoding": "raw",
        "kinds": ["domain"] * 3,
    }
    nrrd.write(str(path), data, header, index_order="F")
    return path


def _assert_phantom(scan: hevr.Scan) -> None:
    assert scan.frame == "RAS"
    np.testing.assert_array_equal(scan.volume, _phantom())
    assert scan.spacing == pytest.approx(SPACING)
    assert scan.origin == pytest.approx(ORIGIN)


def test_nifti_ras_las_and_nrrd_lps_agree(tmp_path: Path) -> None:
    ras = _save_nifti(tmp_path / "ras.nii", *_stored((0, 1, 2), (False, False, False)))
    las = _save_nifti(tmp_path / "las.nii.gz", *_stored((0, 1, 2), (True, False, False)))
    lps = _save_nrrd(tmp_path / "lps.nrrd", *_stored((0, 1, 2), (True, True, False)), "left-posterior-superior")
    scans = [hevr.read_scan(p) for p in (ras, las, lps)]
    for scan in scans:
        _assert_phantom(scan)
    # The stored arrays really differ: the LAS file holds x reversed, the LPS file x and y.
    assert nib.aff2axcodes(nib.load(str(las)).affine) == ("L", "A", "S")
    raw, _ = nrrd.read(str(lps), index_order="C")
    np.testing.assert_array_equal(raw, _phantom()[:, ::-1, ::-1])
    # load_volume gives the same, and the blob at the patient's right-anterior-superior corner
    # is at high x, y and z indices.
    for p in (ras, las, lps):
        vol, spacing = hevr.load_volume(p)
        k, j, i = np.argwhere(vol == 1000).min(axis=0)
        assert (k, j, i) == (SHAPE[0] - 2, SHAPE[1] - 2, SHAPE[2] - 2)
        assert spacing == pytest.approx(SPACING)


def test_blob_on_the_patients_right_ends_at_high_x(tmp_path: Path) -> None:
    data = np.zeros((4, 3, 2), np.uint8)  # (i, j, k) with i running to the patient's LEFT
    data[0, 1, 1] = 9  # i = 0: the rightmost column
    _save_nifti(tmp_path / "las.nii", data, np.diag([-1.0, 1.0, 1.0, 1.0]))
    vol, _ = hevr.load_volume(tmp_path / "las.nii")
    assert vol.shape == (2, 3, 4)
    assert np.argwhere(vol == 9).tolist() == [[1, 1, 3]]  # x = nx - 1: the right side
    assert isinstance(vol, np.memmap)  # reoriented as a view of the memory map


AXES = list(itertools.product(itertools.permutations(range(3)), itertools.product((False, True), repeat=3)))


@pytest.mark.parametrize(
    "perm, flips", AXES, ids=[f"{''.join(map(str, p))}-{''.join('f' if f else '.' for f in fl)}" for p, fl in AXES]
)
def test_every_axis_order_and_flip(tmp_path: Path, perm: tuple[int, ...], flips: tuple[bool, ...]) -> None:
    data, affine = _stored(perm, flips)
    _assert_phantom(hevr.read_scan(_save_nifti(tmp_path / "v.nii", data, affine)))
    space = "left-anterior-superior" if sum(flips) % 2 else "right-anterior-superior"
    _assert_phantom(hevr.read_scan(_save_nrrd(tmp_path / "v.nhdr", data, affine, space)))


def _rotated(degrees: float) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    affine = np.eye(4)
    affine[:2, :2] = [[c, -s], [s, c]]
    return affine


def test_oblique_refused_or_snapped(tmp_path: Path) -> None:
    data = _phantom().transpose(2, 1, 0)
    _save_nifti(tmp_path / "tilt.nii", data, _rotated(10.0))
    with pytest.raises(VolumeFormatError, match=r"tilt\.nii: the scan is oblique: .*10\.00 degrees.*oblique='snap'"):
        hevr.read_scan(tmp_path / "tilt.nii")
    scan = hevr.read_scan(tmp_path / "tilt.nii", oblique="snap")
    np.testing.assert_array_equal(scan.volume, _phantom())
    # Half a degree is within the tolerance: no option needed.
    _save_nifti(tmp_path / "half.nii", data, _rotated(0.5))
    np.testing.assert_array_equal(hevr.load_volume(tmp_path / "half.nii")[0], _phantom())
    with pytest.raises(ParameterError, match="oblique"):
        hevr.read_scan(tmp_path / "half.nii", oblique="resample")


def test_oblique_nrrd(tmp_path: Path) -> None:
    data, _ = _stored((0, 1, 2), (False, False, False))
    _save_nrrd(tmp_path / "o.nrrd", data, _rotated(30.0), "right-anterior-superior")
    with pytest.raises(VolumeFormatError, match=r"o\.nrrd: the scan is oblique"):
        hevr.load_volume(tmp_path / "o.nrrd")
    assert hevr.load_volume(tmp_path / "o.nrrd", oblique="snap")[0].shape == SHAPE


def test_files_without_orientation_keep_their_axes(tmp_path: Path) -> None:
    data, _ = _stored((0, 1, 2), (True, False, False))
    img = nib.Nifti1Image(data, None)  # no sform, no qform: NIfTI "method 1"
    img.header.set_zooms(SPACING)
    img.header.set_sform(None, code=0)
    img.header.set_qform(None, code=0)
    nib.save(img, str(tmp_path / "bare.nii"))
    scan = hevr.read_scan(tmp_path / "bare.nii")
    assert scan.frame is None and scan.spacing == pytest.approx(SPACING)
    np.testing.assert_array_equal(scan.volume, data.transpose(2, 1, 0))
    nrrd.write(
        str(tmp_path / "scanner.nrrd"), data, {"space": "scanner-xyz", "space directions": -np.eye(3)}, index_order="F"
    )
    scan = hevr.read_scan(tmp_path / "scanner.nrrd")
    assert scan.frame is None and scan.spacing == (1.0, 1.0, 1.0)
    np.testing.assert_array_equal(scan.volume, data.transpose(2, 1, 0))
    np.save(tmp_path / "v.npy", _phantom())
    assert hevr.read_scan(tmp_path / "v.npy").frame is None
