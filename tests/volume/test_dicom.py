"""Tests for hevr.volume.dicom: DICOM series folders, rescaling, ordering, errors.

The writers here (``write_slice``, ``write_series``) are shared with test_dicom_series.py and
test_dicom_geometry.py (imported by basename; tests/ has no packages).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hevr.errors import VolumeFormatError
from hevr.volume.dicom import read_dicom, read_dicom_folder
from hevr.volume.loaders import load_volume

AXIAL = (1, 0, 0, 0, 1, 0)


def dataset(pixels: np.ndarray, *, series: str, modality: str = "CT", sop: str | None = None, **attrs: Any) -> Any:
    """A minimal DICOM image dataset holding int16 ``pixels`` (frames, rows, cols) or (rows, cols)."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop or CTImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID
    ds.SeriesInstanceUID, ds.Modality = series, modality
    ds.Rows, ds.Columns = pixels.shape[-2:]
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
    for key, value in attrs.items():
        if value is not None:
            setattr(ds, key, value)
    ds.PixelData = pixels.astype("<i2").tobytes()
    return ds


def write_slice(
    path: Path,
    pixels: np.ndarray,
    *,
    position: Any,
    instance: int | None,
    series: str,
    iop: tuple[float, ...] = AXIAL,
    intercept: float = -1024,
    slope: float = 1,
    spacing: tuple[float, float] = (0.5, 0.7),
    **attrs: Any,
) -> None:
    """One single-frame CT slice; ``spacing`` is PixelSpacing (between rows, between columns)."""
    ds = dataset(
        pixels,
        series=series,
        PixelSpacing=list(spacing),
        SliceThickness=3.0,
        ImagePositionPatient=None if position is None else [float(v) for v in position],
        ImageOrientationPatient=None if position is None else list(iop),
        InstanceNumber=instance,
        RescaleIntercept=intercept,
        RescaleSlope=slope,
        **attrs,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save_as(path, enforce_file_format=True)


def write_series(
    folder: Path,
    stored: np.ndarray,
    *,
    iop: tuple[float, ...] = AXIAL,
    origin: tuple[float, ...] = (10.0, -20.0, 30.0),
    step: Any = None,
    gap: float = 2.5,
    series: str = "1.2.3.4",
    prefix: str = "IM",
    **attrs: Any,
) -> list[Path]:
    """Slice k of ``stored`` (k, rows, cols) at ``origin + k * step`` (default: ``gap`` along the
    normal), files named in scrambled order."""
    normal = np.cross(iop[:3], iop[3:])
    step = gap * normal if step is None else np.asarray(step, np.float64)
    paths = []
    n = len(stored)
    for k in range(n):
        path = folder / f"{prefix}{(k * 7) % n if n % 7 else k:04d}.dcm"
        write_slice(
            path, stored[k], position=np.asarray(origin) + k * step, instance=k + 1, series=series, iop=iop, **attrs
        )
        paths.append(path)
    return paths


def _dicom_series(
    folder: Path, *, iop: tuple[float, ...] = AXIAL, positions: bool = True, slope: float = 1, series: str = "1.2.3.4"
) -> np.ndarray:
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
        write_slice(
            folder / f"IM{k:04d}.dcm", stored[s], position=pos, instance=inst, series=series, iop=iop, slope=slope
        )
    return stored


def test_dicom_series_axial(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    stored = _dicom_series(tmp_path / "ct")
    (tmp_path / "ct" / "README.txt").write_text("not a DICOM file")
    scan = read_dicom(tmp_path / "ct")
    assert scan.volume.dtype == np.int16  # Hounsfield units stay integers
    # i runs to the patient's left (LPS +x) and j to the back: RAS flips both.
    np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1].astype(np.int16) - 1024)
    assert scan.spacing == pytest.approx((0.7, 0.5, 2.5))
    # Voxel (0, 0, 0) is the file's last column and row: LPS (10 + 4*0.7, -20 + 2*0.5, 30).
    assert scan.origin == pytest.approx((-12.8, 19.0, 30.0))
    assert (scan.frame, scan.modality) == ("RAS", "CT")
    assert scan.details["series_uid"] == "1.2.3.4" and scan.details["images"] == scan.details["frames"] == 4
    assert scan.details["transfer_syntax"] == "1.2.840.10008.1.2.1"
    vol, spacing = read_dicom_folder(tmp_path / "ct")  # the old form: the same volume
    np.testing.assert_array_equal(vol, scan.volume)
    assert spacing == scan.spacing


def test_dicom_series_sagittal(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    stored = _dicom_series(tmp_path / "ct", iop=(0, 1, 0, 0, 0, -1))
    scan = read_dicom(tmp_path / "ct")
    # Rows (i) run posterior (-y in RAS), columns (j) inferior (-z), and the slice normal
    # r x c = (-1, 0, 0) in LPS is +x (right) in RAS: x = k, y = nx-1-i, z = ny-1-j.
    expected = stored.transpose(1, 2, 0)[::-1, ::-1, :] - 1024
    np.testing.assert_array_equal(scan.volume, expected)
    assert scan.spacing == pytest.approx((2.5, 0.7, 0.5))
    assert scan.origin == pytest.approx((-10.0, 20.0 - 4 * 0.7, 30.0 - 2 * 0.5))


def test_dicom_instance_number_fallback(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    _dicom_series(tmp_path / "ct", positions=False)
    scan = read_dicom(tmp_path / "ct")
    # Without positions the InstanceNumbers [3, 1, 4, 2] of slices [2, 0, 3, 1] give the
    # order 0, 1, 2, 3 as well; the z spacing falls back to SliceThickness; axes as stored.
    expected = np.arange(60, dtype=np.int16).reshape(4, 3, 5) * 10 - 1024
    np.testing.assert_array_equal(scan.volume, expected)
    assert scan.spacing == pytest.approx((0.7, 0.5, 3.0))
    assert (scan.frame, scan.origin) == (None, (0.0, 0.0, 0.0))
    np.testing.assert_array_equal(load_volume(tmp_path / "ct")[0], expected)


def test_dicom_fractional_slope_gives_float32(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    stored = _dicom_series(tmp_path / "ct", slope=0.5)
    vol = read_dicom(tmp_path / "ct").volume
    assert vol.dtype == np.float32
    np.testing.assert_allclose(vol, stored[:, ::-1, ::-1] * 0.5 - 1024)


def test_dicom_unsigned_storage_becomes_signed_hu(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    folder = tmp_path / "u16"
    folder.mkdir()
    stored = np.array([[0, 1024, 4094]], np.int16)  # + 1 stays within 12 bits
    for k in range(2):
        write_slice(folder / f"s{k}.dcm", stored + k, position=[0, 0, 1.5 * k], instance=k + 1, series="5.6")
    # Rewrite as unsigned 12-bit data, the common CT storage, with the usual intercept.
    import pydicom

    for k in range(2):
        ds = pydicom.dcmread(folder / f"s{k}.dcm")
        ds.PixelRepresentation, ds.BitsStored, ds.HighBit = 0, 12, 11
        ds.PixelData = (stored + k).astype("<u2").tobytes()
        ds.save_as(folder / f"s{k}.dcm")
    scan = read_dicom(folder)
    assert scan.volume.dtype == np.int16
    np.testing.assert_array_equal(scan.volume, np.stack([stored, stored + 1])[:, :, ::-1] - 1024)
    assert scan.spacing == pytest.approx((0.7, 0.5, 1.5))


def test_dicom_per_slice_rescale(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    stored = np.arange(2 * 2 * 3, dtype=np.int16).reshape(2, 2, 3)
    write_slice(tmp_path / "ct" / "a.dcm", stored[0], position=[0, 0, 0], instance=1, series="1", slope=2)
    write_slice(
        tmp_path / "ct" / "b.dcm", stored[1], position=[0, 0, 1], instance=2, series="1", slope=3, intercept=-1000
    )
    vol = read_dicom(tmp_path / "ct").volume
    assert vol.dtype == np.int16
    np.testing.assert_array_equal(vol[0], stored[0, ::-1, ::-1] * 2 - 1024)
    np.testing.assert_array_equal(vol[1], stored[1, ::-1, ::-1] * 3 - 1000)


def test_dicom_errors(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    (tmp_path / "empty").mkdir()
    with pytest.raises(VolumeFormatError, match="empty.*no DICOM"):
        read_dicom(tmp_path / "empty")
    _dicom_series(tmp_path / "dup")
    write_slice(
        tmp_path / "dup" / "copy.dcm",
        np.zeros((3, 5), np.int16),
        position=[10.0, -20.0, 30.0],
        instance=9,
        series="1.2.3.4",
    )
    with pytest.raises(VolumeFormatError, match=r"dup: slices .*(copy\.dcm|IM0001\.dcm).* same position"):
        read_dicom(tmp_path / "dup")
    _dicom_series(tmp_path / "sizes")
    write_slice(
        tmp_path / "sizes" / "big.dcm", np.zeros((4, 5), np.int16), position=[0, 0, 99], instance=9, series="1.2.3.4"
    )
    with pytest.raises(VolumeFormatError, match=r"big\.dcm.*4x5"):
        read_dicom(tmp_path / "sizes")
    _dicom_series(tmp_path / "scout")  # a localizer in the series: another orientation
    write_slice(
        tmp_path / "scout" / "loc.dcm",
        np.zeros((3, 5), np.int16),
        position=[0, 0, 99],
        instance=9,
        series="1.2.3.4",
        iop=(0, 1, 0, 0, 0, -1),
    )
    with pytest.raises(VolumeFormatError, match=r"scout: ImageOrientationPatient.*loc\.dcm.*localizer"):
        read_dicom(tmp_path / "scout")
    _dicom_series(tmp_path / "shift")  # one slice moved within its plane
    write_slice(
        tmp_path / "shift" / "moved.dcm",
        np.zeros((3, 5), np.int16),
        position=[15.0, -20.0, 40.0],
        instance=9,
        series="1.2.3.4",
    )
    with pytest.raises(VolumeFormatError, match=r"shift: slice moved\.dcm is shifted 5 mm"):
        read_dicom(tmp_path / "shift")
    with pytest.raises(FileNotFoundError, match="nothing at"):
        read_dicom(tmp_path / "absent")
    one = tmp_path / "single.dcm"
    one.write_bytes(b"")
    with pytest.raises(VolumeFormatError, match=r"single\.dcm.*(folder|no DICOM file)"):
        load_volume(one)
    with pytest.raises(VolumeFormatError, match=r"^single\.dcm: expected a DICOM image file.*got no DICOM file"):
        read_dicom(one)


def test_a_single_file_that_stands_for_its_series_says_so_in_errors(tmp_path: Path) -> None:
    """Issue 39, item 10: an error about a sibling file named a file the user never gave;
    it now says why that file was read, and how to read the one file alone."""
    pytest.importorskip("pydicom")
    _dicom_series(tmp_path / "s")
    write_slice(
        tmp_path / "s" / "big.dcm", np.zeros((4, 5), np.int16), position=[0, 0, 99], instance=9, series="1.2.3.4"
    )
    with pytest.raises(VolumeFormatError) as info:
        read_dicom(tmp_path / "s" / "IM0000.dcm")
    text = str(info.value)
    assert "big.dcm" in text and "4x5" in text  # the sibling at fault, as before
    assert (
        "IM0000.dcm is one slice of series 1.2.3.4: a single-frame DICOM file stands for its series, so the "
        "4 other files of it in"
    ) in text
    assert "to read IM0000.dcm alone, put it in a folder of its own" in text
    (tmp_path / "alone").mkdir()
    (tmp_path / "s" / "IM0000.dcm").rename(tmp_path / "alone" / "IM0000.dcm")
    assert read_dicom(tmp_path / "alone" / "IM0000.dcm").volume.shape[0] == 1  # the advice works
    with pytest.raises(VolumeFormatError) as info:
        read_dicom(tmp_path / "s")  # a folder the user named: no such note
    assert "stands for its series" not in str(info.value)
