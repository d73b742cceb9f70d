"""Tests for hevr.volume.dicom_mosaic: Siemens MOSAIC images unpacked into their slices.

The files are nibabel's own Siemens test data (``nibabel/nicom/tests/data``): two diffusion
mosaics of one series (b = 0 and b = 1000, 48 slices of 128 × 128 on a 7 × 7 grid, pixels
zeroed by nibabel to keep them small) and ``0.dcm``, whose header declares 48 slices but whose
pixel data is 256 × 256. The trusted reference is nibabel's ``MosaicWrapper`` (its slices and
its voxel → patient affine). Issue 29, item 2.
"""

from __future__ import annotations

import gzip
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hevr.errors import CorruptVolumeError, VolumeFormatError
from hevr.volume.dicom import list_series, read_dicom
from hevr.volume.dicom_mosaic import Mosaic, grid_of, untile

nib = pytest.importorskip("nibabel")
pydicom = pytest.importorskip("pydicom")
DATA = Path(nib.__file__).parent / "nicom" / "tests" / "data"


def _dwi(tmp_path: Path, b: int, pattern: bool = True) -> Path:
    """nibabel's ``siemens_dwi_{b}.dcm.gz`` as a .dcm, its zeroed tiles given distinct values."""
    with gzip.open(DATA / f"siemens_dwi_{b}.dcm.gz") as fh:
        ds = pydicom.dcmread(fh)
    if pattern:
        m, r, c, n = 7, 128, 128, 48
        tiles = np.zeros((m * m, r, c), np.uint16)
        rr, cc = np.mgrid[0:r, 0:c]
        for k in range(n):  # unique within a tile; neighbouring tiles differ in the top bits
            tiles[k] = (k % 4) * 16384 + rr * 128 + cc + (b > 0)
        mosaic = tiles.reshape(m, m, r, c).transpose(0, 2, 1, 3).reshape(m * r, m * c)
        ds.PixelData = mosaic.astype("<u2").tobytes()
        ds.BitsStored, ds.HighBit = 16, 15  # the file says 12: the pattern needs all 16 bits
    path = tmp_path / f"dwi_{b}.dcm"
    ds.save_as(path)
    return path


def test_untile_is_the_inverse_of_tiling():
    n, m, r, c = 5, grid_of(5), 2, 3
    slices = np.arange(n * r * c).reshape(n, r, c)
    grid = np.zeros((m * m, r, c), int)
    grid[:n] = slices
    image = grid.reshape(m, m, r, c).transpose(0, 2, 1, 3).reshape(m * r, m * c)
    assert np.array_equal(untile(image, Mosaic(n, m, r, c, None)), slices)


@pytest.mark.filterwarnings("ignore:The DICOM readers are highly experimental")
def test_mosaic_matches_nibabel(tmp_path):
    """The 48 slices, their order and their place in the patient frame, as nibabel has them."""
    path = _dwi(tmp_path, 1000)
    scan = read_dicom(path)
    assert scan.volume.shape == (48, 128, 128)
    assert scan.details["images"] == 1 and scan.details["frames"] == 48
    assert scan.spacing == pytest.approx((1.796875, 1.796875, 3.0))
    from nibabel.nicom import dicomwrappers
    from nibabel.orientations import apply_orientation, io_orientation

    wrapper = dicomwrappers.wrapper_from_file(str(path))
    ras = np.diag([-1.0, -1.0, 1.0, 1.0]) @ wrapper.affine  # nibabel's (row, column, slice) -> LPS -> RAS
    data = np.asarray(wrapper.get_data())
    expected = apply_orientation(data, io_orientation(ras))  # (x, y, z) in RAS+ order
    assert np.array_equal(scan.volume, expected.transpose(2, 1, 0))
    # The first voxel of the RAS+ array lies where nibabel puts that voxel.
    corner = [0 if sign > 0 else size - 1 for (_, sign), size in zip(io_orientation(ras), data.shape)]
    assert np.allclose(scan.origin, (ras @ [*corner, 1])[:3], atol=1e-3)


def test_one_file_of_a_diffusion_series_reads_that_volume(tmp_path):
    """b = 0 and b = 1000 in one folder: the folder is refused (same positions twice) with the
    way out; naming one file reads that file only, not its series' other mosaic."""
    b0, b1000 = _dwi(tmp_path, 0), _dwi(tmp_path, 1000)
    with pytest.raises(VolumeFormatError, match="same position.*each file holds a whole volume: name one file"):
        read_dicom(tmp_path)
    (info,) = list_series(tmp_path)  # the listing counts slices, not tiles
    assert (info.images, info.frames, info.rows, info.columns) == (2, 96, 128, 128)
    v0, v1000 = read_dicom(b0), read_dicom(b1000)
    assert v0.volume.shape == v1000.volume.shape == (48, 128, 128)
    assert np.array_equal(v1000.volume, v0.volume + 1)  # each file's own pixels


def test_mosaic_that_cannot_hold_its_slices_is_refused():
    """nibabel's 0.dcm: 48 slices declared, 256 × 256 pixels (7 does not divide 256). Read as
    two 256 × 256 slices it was a plausible wrong volume; now it is a data error."""
    with pytest.raises(
        CorruptVolumeError,
        match=r"0\.dcm: a Siemens MOSAIC of 48 slices on a 7x7 grid: "
        r"expected rows and columns that are multiples of 7, got 256x256",
    ):
        read_dicom(DATA / "0.dcm")


def test_mosaic_without_its_slice_count_is_refused(tmp_path):
    with gzip.open(DATA / "siemens_dwi_0.dcm.gz") as fh:
        ds = pydicom.dcmread(fh)
    del ds[0x00291010]  # the CSA image header
    ds.save_as(tmp_path / "bare.dcm")
    with pytest.raises(VolumeFormatError, match="bare.dcm: a Siemens MOSAIC .*expected NumberOfImagesInMosaic"):
        read_dicom(tmp_path / "bare.dcm")


def test_cli_info_and_exit_status(tmp_path):
    """``hevr info`` shows the unpacked size; the inconsistent mosaic exits 1 (failed data)."""
    path = _dwi(tmp_path, 1000, pattern=False)
    shutil.copy(DATA / "0.dcm", tmp_path / "bad.dcm")
    ok = subprocess.run([sys.executable, "-m", "hevr", "info", str(path)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert "128x128x48" in ok.stdout.replace(" ", "").replace("×", "x")
    assert "warning" not in ok.stderr, ok.stderr  # nibabel's note on its own DICOM readers is not the user's
    bad = subprocess.run(
        [sys.executable, "-m", "hevr", "info", str(tmp_path / "bad.dcm")], capture_output=True, text=True
    )
    assert bad.returncode == 1 and "multiples of 7, got 256x256" in bad.stderr


def test_listing_a_mosaic_without_nibabel(tmp_path, monkeypatch):
    """Without nibabel a folder holding a mosaic is still listed (as stored); reading it says
    what is missing."""
    import hevr.volume.dicom_mosaic as mosaic_mod
    from hevr.errors import MissingDependencyError

    _dwi(tmp_path, 0, pattern=False)

    def missing(module, path):
        raise MissingDependencyError(f"reading {path.name} needs the optional package '{module}'")

    monkeypatch.setattr(mosaic_mod, "require", missing)
    (info,) = list_series(tmp_path)
    assert (info.images, info.frames, info.rows, info.columns) == (1, 1, 896, 896)
    with pytest.raises(MissingDependencyError, match="nibabel"):
        read_dicom(tmp_path / "dwi_0.dcm")
