"""Tests for DICOM geometry: orientations into RAS+, spacing checks, tilt, multi-frame files, colour."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_dicom import AXIAL, dataset, write_series, write_slice

from hevr.errors import VolumeFormatError
from hevr.volume.dicom import read_dicom

pytest.importorskip("pydicom")

# A patient on a lattice: LPS point P0 + (a*hx, b*hy, c*hz) has the value V[c, b, a].
H = np.array([0.7, 0.5, 2.5])
P0 = np.array([-30.0, 12.0, 80.0])
NA, NB, NC = 5, 4, 3
V = (100 * np.arange(NC)[:, None, None] + 10 * np.arange(NB)[None, :, None] + np.arange(NA)[None, None, :]).astype(
    np.int16
)
# In RAS+ x runs to the right (LPS -x) and y to the front (LPS -y): both lattice axes flip.
EXPECTED = V[:, ::-1, ::-1]
EXPECTED_ORIGIN = (-(P0[0] + (NA - 1) * H[0]), -(P0[1] + (NB - 1) * H[1]), P0[2])


def _acquire(folder: Path, iop: tuple[float, ...], series: str = "1.9") -> None:
    """Write the lattice patient as slices with orientation ``iop`` (axis-aligned directions)."""
    r, c = np.array(iop[:3], float), np.array(iop[3:], float)
    n = np.cross(r, c)
    size = np.array([NA, NB, NC])
    axis = [int(np.argmax(np.abs(v))) for v in (r, c, n)]
    # Voxel (0, 0, 0) of the acquisition: the lattice corner its directions start from.
    start = np.array([(size[w] - 1 if v[w] < 0 else 0) for w, v in zip(axis, (r, c, n))])
    corner = np.zeros(3, int)
    for w, s in zip(axis, start):
        corner[w] = s
    cols, rows, slices = size[axis[0]], size[axis[1]], size[axis[2]]
    for k in range(slices):
        pix = np.empty((rows, cols), np.int16)
        for j in range(rows):
            for i in range(cols):
                a, b, cc = corner + (i * r + j * c + k * n).round().astype(int)
                pix[j, i] = V[cc, b, a]
        ipp = P0 + (corner + k * n) * H
        write_slice(
            folder / f"s{(k * 2) % slices}_{k}.dcm",
            pix,
            position=ipp,
            instance=k + 1,
            series=series,
            iop=iop,
            intercept=0,
            spacing=(H[axis[1]], H[axis[0]]),
        )


@pytest.mark.parametrize(
    "iop",
    [AXIAL, (-1, 0, 0, 0, -1, 0), (0, 1, 0, 0, 0, -1), (1, 0, 0, 0, 0, -1), (0, -1, 0, 1, 0, 0)],
    ids=["axial", "axial-flipped", "sagittal", "coronal", "axial-rotated"],
)
def test_every_orientation_gives_the_same_ras_volume(tmp_path: Path, iop: tuple[float, ...]) -> None:
    _acquire(tmp_path / "s", iop)
    scan = read_dicom(tmp_path / "s")
    np.testing.assert_array_equal(scan.volume, EXPECTED)
    assert scan.spacing == pytest.approx(tuple(H))
    assert scan.origin == pytest.approx(EXPECTED_ORIGIN)
    assert scan.frame == "RAS"


def test_blob_at_patients_left_ends_at_low_x(tmp_path: Path) -> None:
    stored = np.zeros((3, 4, 6), np.int16)
    stored[1, 1, 5] = 1000  # last column: DICOM +x, the patient's left; row 1: near the front
    stored[1, 1, 4] = 500  # asymmetric: the weaker voxel lies towards the right
    write_series(tmp_path / "s", stored, intercept=0)
    vol = read_dicom(tmp_path / "s").volume
    assert vol.shape == (3, 4, 6)
    z, y, x = np.unravel_index(np.argmax(vol), vol.shape)
    assert (z, y, x) == (1, 2, 0)  # left = low x in RAS; row 1 of 4 from the front = y index 2
    assert vol[1, 2, 1] == 500


def test_uneven_spacing_refused_or_allowed(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    stored = np.arange(4 * 2 * 3, dtype=np.int16).reshape(4, 2, 3)
    for k, z in enumerate([0.0, 2.5, 5.0, 10.0]):  # the slice at 7.5 is missing
        write_slice(tmp_path / "gap" / f"z{k}.dcm", stored[k], position=[0, 0, z], instance=k + 1, series="1")
    with pytest.raises(
        VolumeFormatError,
        match=r"^gap: uneven slice spacing: expected the slices 2\.5 mm apart.*"
        r"z2\.dcm to z3\.dcm: 5 mm.*allow_uneven=True",
    ):
        read_dicom(tmp_path / "gap")
    with caplog.at_level(logging.WARNING, logger="hevr.volume"):
        scan = read_dicom(tmp_path / "gap", allow_uneven=True)
    assert "uneven slice spacing" in caplog.text
    np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1] - 1024)
    assert scan.spacing == pytest.approx((0.7, 0.5, 2.5)) and scan.details["uneven_spacing"] is True
    for name, last, ok in (("two-percent", 5.05, False), ("half-percent", 5.0125, True)):
        for k, z in enumerate([0.0, 2.5, last]):
            write_slice(tmp_path / name / f"z{k}.dcm", stored[k], position=[0, 0, z], instance=k + 1, series="1")
        if ok:
            assert read_dicom(tmp_path / name).spacing[2] == pytest.approx(2.5, rel=0.01)
        else:
            with pytest.raises(VolumeFormatError, match="uneven"):
                read_dicom(tmp_path / name)


def test_gantry_tilt_refused_or_snapped(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    stored = np.arange(3 * 2 * 3, dtype=np.int16).reshape(3, 2, 3)
    step = (0.0, 2.5 * math.tan(math.radians(15)), 2.5)  # each slice 0.67 mm further back
    write_series(tmp_path / "tilt", stored, step=step)
    with pytest.raises(VolumeFormatError, match=r"^tilt: .*gantry tilt of 15\.00 degrees.*oblique='snap'"):
        read_dicom(tmp_path / "tilt")
    with caplog.at_level(logging.WARNING, logger="hevr.volume"):
        scan = read_dicom(tmp_path / "tilt", oblique="snap")
    assert "gantry tilt of 15.00 degrees" in caplog.text
    np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1] - 1024)
    assert scan.spacing == pytest.approx((0.7, 0.5, 2.5))  # the distance between the planes


def test_oblique_plane_refused_or_snapped(tmp_path: Path) -> None:
    t = math.radians(10)
    iop = (math.cos(t), math.sin(t), 0, -math.sin(t), math.cos(t), 0)  # axial, rotated 10 degrees
    stored = np.arange(3 * 2 * 3, dtype=np.int16).reshape(3, 2, 3)
    write_series(tmp_path / "obl", stored, iop=iop)
    with pytest.raises(VolumeFormatError, match=r"^obl: the scan is oblique.*10\.00 degrees"):
        read_dicom(tmp_path / "obl")
    scan = read_dicom(tmp_path / "obl", oblique="snap")
    np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1] - 1024)


def test_colour_refused(tmp_path: Path) -> None:
    ds = dataset(
        np.zeros((2, 3), np.int16),
        series="1",
        ImagePositionPatient=[0, 0, 0],
        ImageOrientationPatient=list(AXIAL),
        PixelSpacing=[1, 1],
    )
    ds.SamplesPerPixel, ds.PhotometricInterpretation, ds.PlanarConfiguration = 3, "RGB", 0
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 8, 8, 7, 0
    ds.PixelData = np.zeros((2, 3, 3), np.uint8).tobytes()
    ds.save_as(tmp_path / "photo.dcm", enforce_file_format=True)
    with pytest.raises(VolumeFormatError, match=r"^photo\.dcm: expected greyscale.*3 sample\(s\) per pixel, RGB"):
        read_dicom(tmp_path / "photo.dcm")


def _sequence(**attrs: Any) -> Any:
    from pydicom.dataset import Dataset
    from pydicom.sequence import Sequence

    item = Dataset()
    for key, value in attrs.items():
        setattr(item, key, value)
    return Sequence([item])


def _enhanced(
    path: Path,
    stored: np.ndarray,
    positions: list[list[float]],
    slopes: list[float],
    intercepts: list[float],
    iop: tuple[float, ...],
) -> None:
    """An Enhanced CT file: geometry and pixel size shared, positions and rescale per frame."""
    from pydicom.dataset import Dataset
    from pydicom.sequence import Sequence

    ds = dataset(stored, series="2.2.2", sop="1.2.840.10008.5.1.4.1.1.2.1", NumberOfFrames=len(stored))
    shared = Dataset()
    shared.PlaneOrientationSequence = _sequence(ImageOrientationPatient=list(iop))
    shared.PixelMeasuresSequence = _sequence(PixelSpacing=[0.5, 0.7], SliceThickness=2.5)
    ds.SharedFunctionalGroupsSequence = Sequence([shared])
    per = []
    for pos, slope, inter in zip(positions, slopes, intercepts):
        item = Dataset()
        item.PlanePositionSequence = _sequence(ImagePositionPatient=pos)
        item.PixelValueTransformationSequence = _sequence(RescaleSlope=slope, RescaleIntercept=inter, RescaleType="HU")
        per.append(item)
    ds.PerFrameFunctionalGroupsSequence = Sequence(per)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save_as(path, enforce_file_format=True)


@pytest.mark.parametrize("iop", [AXIAL, (0, 1, 0, 0, 0, -1)], ids=["axial", "sagittal"])
def test_enhanced_multiframe_equals_single_frames(tmp_path: Path, iop: tuple[float, ...]) -> None:
    stored = np.arange(4 * 3 * 5, dtype=np.int16).reshape(4, 3, 5) * 3
    normal = np.cross(iop[:3], iop[3:])
    positions = [(np.array([10.0, -20.0, 30.0]) + 2.5 * k * normal).tolist() for k in range(4)]
    slopes, intercepts = [1, 1, 2, 1], [-1024, -1000, -1024, -1024]
    frame_order = [2, 0, 3, 1]  # frames stored out of position order
    _enhanced(
        tmp_path / "enh" / "ct.dcm",
        stored[frame_order],
        [positions[k] for k in frame_order],
        [slopes[k] for k in frame_order],
        [intercepts[k] for k in frame_order],
        iop,
    )
    for k in range(4):
        write_slice(
            tmp_path / "single" / f"s{k}.dcm",
            stored[k],
            position=positions[k],
            instance=k + 1,
            series="3.3",
            iop=iop,
            slope=slopes[k],
            intercept=intercepts[k],
        )
    single = read_dicom(tmp_path / "single")
    for path in (tmp_path / "enh", tmp_path / "enh" / "ct.dcm"):  # the folder or the file
        enhanced = read_dicom(path)
        np.testing.assert_array_equal(enhanced.volume, single.volume)
        assert enhanced.volume.dtype == single.volume.dtype == np.int16
        assert enhanced.spacing == pytest.approx(single.spacing)
        assert enhanced.origin == pytest.approx(single.origin)
        assert enhanced.details["images"] == 1 and enhanced.details["frames"] == 4


def test_legacy_multiframe_nm_style(tmp_path: Path) -> None:
    stored = np.arange(3 * 2 * 4, dtype=np.int16).reshape(3, 2, 4)
    ds = dataset(
        stored,
        series="4.4",
        modality="NM",
        sop="1.2.840.10008.5.1.4.1.1.20",
        NumberOfFrames=3,
        PixelSpacing=[2.0, 3.0],
        SpacingBetweenSlices=4.0,
        DetectorInformationSequence=_sequence(
            ImagePositionPatient=[0.0, 0.0, 0.0], ImageOrientationPatient=list(AXIAL)
        ),
    )
    ds.save_as(tmp_path / "nm.dcm", enforce_file_format=True)
    scan = read_dicom(tmp_path / "nm.dcm")
    np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1])
    assert scan.spacing == pytest.approx((3.0, 2.0, 4.0)) and scan.modality == "NM"


@pytest.mark.filterwarnings("ignore:Expected explicit VR")  # from siblings read for CT_small's series
def test_pydicom_bundled_files() -> None:
    """Files pydicom ships (no network): a CT slice and a legacy multi-frame RT dose grid."""
    import pydicom
    from pydicom.data import get_testdata_file

    ct = get_testdata_file("CT_small.dcm", download=False)
    assert ct is not None
    ds = pydicom.dcmread(ct)
    scan = read_dicom(ct)
    expected = ds.pixel_array.astype(np.int16) * int(ds.RescaleSlope) + int(ds.RescaleIntercept)
    np.testing.assert_array_equal(scan.volume, expected[None, ::-1, ::-1])
    assert scan.spacing == pytest.approx((*[float(v) for v in ds.PixelSpacing], float(ds.SliceThickness)))
    assert scan.modality == "CT" and scan.details["series_uid"] == ds.SeriesInstanceUID
    dose = get_testdata_file("rtdose.dcm", download=False)
    assert dose is not None
    scan = read_dicom(dose)  # GridFrameOffsetVector 0, 5, ... 70 mm; DoseGridScaling to Gy
    ds = pydicom.dcmread(dose)
    assert scan.volume.shape == (15, 10, 10) and scan.spacing == pytest.approx((10.0, 10.0, 5.0))
    np.testing.assert_allclose(scan.volume, (ds.pixel_array * float(ds.DoseGridScaling))[:, ::-1, ::-1], rtol=1e-6)
    assert scan.origin[2] == pytest.approx(float(ds.ImagePositionPatient[2]))
