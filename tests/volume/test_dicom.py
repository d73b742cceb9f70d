"""Tests for hevr.volume.dicom: DICOM series, multi-frame files, DICOMDIR, series choice."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hevr.errors import VolumeFormatError
from hevr.volume.loaders import load_volume


def _write_dicom_slice(path: Path, pixels: np.ndarray, *, position: list[float] | None,
                       instance: int | None, series: str, iop: tuple[float, ...] = (1, 0, 0, 0, 1, 0),
                       intercept: float = -1024, slope: float = 1) -> None:
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = CTImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
    ds.SeriesInstanceUID, ds.Modality = series, "CT"
    ds.Rows, ds.Columns = pixels.shape
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
    ds.PixelSpacing = [0.5, 0.7]  # (between rows = sy, between columns = sx)
    ds.SliceThickness = 3.0
    if position is not None:
        ds.ImagePositionPatient = position
        ds.ImageOrientationPatient = list(iop)
    if instance is not None:
        ds.InstanceNumber = instance
    ds.RescaleIntercept, ds.RescaleSlope = intercept, slope
    ds.PixelData = pixels.astype("<i2").tobytes()
    ds.save_as(path, enforce_file_format=True)


def _dicom_series(folder: Path, *, iop: tuple[float, ...] = (1, 0, 0, 0, 1, 0), positions: bool = True,
                  slope: float = 1, series: str = "1.2.3.4") -> np.ndarray:
    """Write 4 int16 slices 2.5 mm apart, in scrambled file and InstanceNumber order.

    Returns the expected stored values (before rescaling) in ascending slice-normal order.
    """
    folder.mkdir(exist_ok=True)
    normal = np.cross(iop[:3], iop[3:])
    stored = np.arange(4 * 3 * 5, dtype=np.int16).reshape(4, 3, 5) * 10
    # File k (in name order) holds slice order[k]; InstanceNumbers disagree with the
    # positions on purpose, so a reader trusting them (or the names) gets it wrong.
    order, instances = [2, 0, 3, 1], [1, 2, 3, 4] if positions else [3, 1, 4, 2]
    for k, (s, inst) in enumerate(zip(order, instances)):
        pos = (np.array([10.0, -20.0, 30.0]) + 2.5 * s * normal).tolist() if positions else None
        _write_dicom_slice(folder / f"IM{k:04d}.dcm", stored[s], position=pos, instance=inst,
                           series=series, iop=iop, slope=slope)
    return stored


@pytest.mark.parametrize("iop", [(1, 0, 0, 0, 1, 0), (0, 1, 0, 0, 0, -1)], ids=["axial", "sagittal"])
def test_dicom_series(tmp_path: Path, iop: tuple[float, ...]) -> None:
    pytest.importorskip("pydicom")
    stored = _dicom_series(tmp_path / "ct", iop=iop)
    (tmp_path / "ct" / "README.txt").write_text("not a DICOM file")
    vol, spacing = load_volume(tmp_path / "ct")
    assert vol.dtype == np.int16  # Hounsfield units stay integers
    np.testing.assert_array_equal(vol, stored.astype(np.int16) - 1024)
    assert spacing == pytest.approx((0.7, 0.5, 2.5))


def test_dicom_instance_number_fallback(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    _dicom_series(tmp_path / "ct", positions=False)
    vol, spacing = load_volume(tmp_path / "ct")
    # Without positions the InstanceNumbers [3, 1, 4, 2] of slices [2, 0, 3, 1] give the
    # order 0, 1, 2, 3 as well; the z spacing falls back to SliceThickness.
    expected = np.arange(60, dtype=np.int16).reshape(4, 3, 5) * 10 - 1024
    np.testing.assert_array_equal(vol, expected)
    assert spacing == pytest.approx((0.7, 0.5, 3.0))


def test_dicom_fractional_slope_gives_float32(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    stored = _dicom_series(tmp_path / "ct", slope=0.5)
    vol, _ = load_volume(tmp_path / "ct")
    assert vol.dtype == np.float32
    np.testing.assert_allclose(vol, stored * 0.5 - 1024)


def test_dicom_unsigned_storage_becomes_signed_hu(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    folder = tmp_path / "u16"
    folder.mkdir()
    stored = np.array([[0, 1024, 4094]], np.int16)  # + 1 stays within 12 bits
    for k in range(2):
        _write_dicom_slice(folder / f"s{k}.dcm", stored + k, position=[0, 0, 1.5 * k],
                           instance=k + 1, series="5.6")
    # Rewrite as unsigned 12-bit data, the common CT storage, with the usual intercept.
    import pydicom

    for k in range(2):
        ds = pydicom.dcmread(folder / f"s{k}.dcm")
        ds.PixelRepresentation, ds.BitsStored, ds.HighBit = 0, 12, 11
        ds.PixelData = (stored + k).astype("<u2").tobytes()
        ds.save_as(folder / f"s{k}.dcm")
    vol, spacing = load_volume(folder)
    assert vol.dtype == np.int16
    np.testing.assert_array_equal(vol, np.stack([stored, stored + 1]) - 1024)
    assert spacing == pytest.approx((0.7, 0.5, 1.5))


def test_dicom_errors(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    (tmp_path / "empty").mkdir()
    with pytest.raises(VolumeFormatError, match="empty.*no DICOM"):
        load_volume(tmp_path / "empty")
    _dicom_series(tmp_path / "mixed")
    _write_dicom_slice(tmp_path / "mixed" / "other.dcm", np.zeros((3, 5), np.int16),
                       position=[0, 0, 99], instance=9, series="9.9.9")
    with pytest.raises(VolumeFormatError, match="mixed.*one DICOM series"):
        load_volume(tmp_path / "mixed")
    _dicom_series(tmp_path / "dup")
    _write_dicom_slice(tmp_path / "dup" / "copy.dcm", np.zeros((3, 5), np.int16),
                       position=[10.0, -20.0, 30.0], instance=9, series="1.2.3.4")
    with pytest.raises(VolumeFormatError, match="dup.*same position"):
        load_volume(tmp_path / "dup")
    _dicom_series(tmp_path / "sizes")
    _write_dicom_slice(tmp_path / "sizes" / "big.dcm", np.zeros((4, 5), np.int16),
                       position=[0, 0, 99], instance=9, series="1.2.3.4")
    with pytest.raises(VolumeFormatError, match=r"big\.dcm.*4x5"):
        load_volume(tmp_path / "sizes")
    one = tmp_path / "single.dcm"
    one.write_bytes(b"")
    with pytest.raises(VolumeFormatError, match=r"single\.dcm.*folder"):
        load_volume(one)


