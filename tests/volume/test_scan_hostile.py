"""hevr.read_scan on hostile real-scan files written by the formats' own libraries (nibabel,
pydicom, tifffile, zarr): each one a bug found by a hostile review. Every refusal is a
VolumeFormatError/ParameterError naming the file or parameter, fast and in bounded memory;
accepted files come back with the right values, spacing and memory maps."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import hevr
from hevr.errors import ParameterError, VolumeFormatError
from hevr.volume import _memory
from hevr.volume.mapped import file_backed
from hevr.volume.orientation import to_patient_frame

nib = pytest.importorskip("nibabel")

VOL = np.arange(4 * 5 * 6, dtype=np.int16).reshape(6, 5, 4)  # nibabel order (x, y, z)


def _small_memory(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pretend the machine has 100 kB, so that "bigger than memory" costs nothing to test."""
    monkeypatch.setattr(_memory, "physical_memory", lambda: 100_000)


def _nifti_header(shape: tuple[int, ...]) -> bytes:
    hdr = nib.Nifti1Header()
    hdr.set_data_shape(shape)
    hdr.set_data_dtype(np.int16)
    hdr["vox_offset"] = 352
    return hdr.binaryblock + bytes(4)


# -- NIfTI ------------------------------------------------------------------------------------
def test_nifti_memory_map_is_read_only_and_file_backed(tmp_path: Path) -> None:
    """nibabel maps copy-on-write ("c") by default: writeable, so mapped.file_backed refused it
    and the whole volume went into the task graph."""
    nib.save(nib.Nifti1Image(VOL, np.diag([-1.0, 1.0, 1.0, 1.0])), tmp_path / "a.nii")
    vol = hevr.load_volume(tmp_path / "a.nii")[0]
    assert isinstance(vol, np.memmap) and not vol.flags.writeable
    mapped = file_backed(vol)
    assert mapped is not None
    np.testing.assert_array_equal(mapped[:, 1:, ::2], np.asarray(vol)[:, 1:, ::2])


def test_truncated_nifti_is_refused_before_reading(tmp_path: Path) -> None:
    """nibabel allocated the declared size (here 54 TB) before noticing the file is short."""
    path = tmp_path / "short.nii"
    path.write_bytes(_nifti_header((30000, 30000, 30000)) + bytes(100))
    with pytest.raises(VolumeFormatError, match=r"^short\.nii: truncated: .*\(30000, 30000, 30000\)"):
        hevr.load_volume(path)


def test_compressed_nifti_larger_than_memory_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import gzip

    path = tmp_path / "big.nii.gz"
    path.write_bytes(gzip.compress(_nifti_header((200, 200, 200)) + bytes(100)))
    _small_memory(monkeypatch)
    with pytest.raises(VolumeFormatError, match=r"^big\.nii\.gz: too big: 16000000 bytes"):
        hevr.load_volume(path)


@pytest.mark.parametrize("slope", [1e30, 2.0**40])
def test_integral_slope_beyond_int64_gives_float64(tmp_path: Path, slope: float) -> None:
    """rescale looked for an integer type holding the values and raised StopIteration."""
    img = nib.Nifti1Image(np.full((2, 2, 2), 2**31 - 1, np.int32), np.eye(4))
    img.header.set_slope_inter(slope, 0)
    nib.save(img, tmp_path / "s.nii")
    vol = hevr.load_volume(tmp_path / "s.nii")[0]
    assert vol.dtype == np.float64 and np.isfinite(vol).all()
    assert vol[0, 0, 0] == pytest.approx((2**31 - 1) * slope)


# -- DICOM ------------------------------------------------------------------------------------
def _enhanced(tmp_path: Path, edit: Any = None) -> Path:
    from test_dicom import AXIAL
    from test_dicom_geometry import _enhanced as write

    path = tmp_path / "enh" / "e.dcm"
    stored = np.arange(4 * 3 * 5, dtype=np.int16).reshape(4, 3, 5)
    write(path, stored, [[0.0, 0.0, 2.5 * k] for k in range(4)], [1] * 4, [0] * 4, AXIAL)
    if edit is not None:
        import pydicom

        ds = pydicom.dcmread(path)
        edit(ds)
        ds.save_as(path)
    return path


def test_forged_number_of_frames_is_refused_at_once(tmp_path: Path) -> None:
    """10**7 frames in an 800-byte file built 10**7 Frame objects first: 13 minutes."""
    pytest.importorskip("pydicom")

    def forge(ds: Any) -> None:
        ds.NumberOfFrames = 10**7
        del ds.PerFrameFunctionalGroupsSequence

    path = _enhanced(tmp_path, forge)
    t0 = time.perf_counter()
    with pytest.raises(VolumeFormatError, match=r"^e\.dcm: NumberOfFrames: 10000000 frames need at least"):
        hevr.read_scan(path)
    assert time.perf_counter() - t0 < 2


@pytest.mark.parametrize(
    "tag, where",
    [(0x00209113, "item"), (0x52009229, "top"), (0x00540022, "top")],
    ids=["PlanePositionSequence", "SharedFunctionalGroupsSequence", "DetectorInformationSequence"],
)
def test_functional_group_that_is_not_a_sequence(tmp_path: Path, tag: int, where: str) -> None:
    """A sequence written as a string: AttributeError ('str' has no 'get'), or silently ignored."""
    pytest.importorskip("pydicom")

    def edit(ds: Any) -> None:
        (ds.PerFrameFunctionalGroupsSequence[1] if where == "item" else ds).add_new(tag, "LO", "abc")

    with pytest.raises(VolumeFormatError, match=r"Sequence: expected a sequence of items, got 'abc'"):
        hevr.read_scan(_enhanced(tmp_path, edit))


def test_frames_without_position_among_placed_ones_are_refused(tmp_path: Path) -> None:
    """One frame without its PlanePositionSequence made the whole file lose its orientation."""
    pytest.importorskip("pydicom")
    path = _enhanced(tmp_path, lambda ds: delattr(ds.PerFrameFunctionalGroupsSequence[2], "PlanePositionSequence"))
    with pytest.raises(VolumeFormatError, match=r"e\.dcm frame 3 lacks ImagePositionPatient"):
        hevr.read_scan(path)


def test_dicom_series_larger_than_memory_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("pydicom")
    from test_dicom import write_series

    write_series(tmp_path / "s", np.zeros((3, 300, 300), np.int16))
    _small_memory(monkeypatch)
    with pytest.raises(VolumeFormatError, match=r"^s: too big: 540000 bytes of DICOM pixel data"):
        hevr.read_scan(tmp_path / "s")


def test_dicom_huge_rescale_slope(tmp_path: Path) -> None:
    pytest.importorskip("pydicom")
    from test_dicom import write_series

    write_series(tmp_path / "s", np.ones((2, 3, 4), np.int16), slope=1e300, intercept=0)
    vol = hevr.read_scan(tmp_path / "s").volume
    assert vol.dtype == np.float64 and np.all(vol == 1e300)


# -- geometry and parameters ------------------------------------------------------------------
def test_voxel_steps_overflowing_their_length() -> None:
    """|(1e300, 0, 0)| overflows to inf: the axes were reported '90 degrees oblique'."""
    with pytest.raises(VolumeFormatError, match=r"^v: expected voxel sizes within floating-point range"):
        to_patient_frame(np.zeros((2, 2, 2)), np.diag([1e300, 1e300, 1.0, 1.0]), name="v")


@pytest.mark.parametrize("path", [None, 3, b"a.nii"])
def test_path_of_the_wrong_type(path: Any) -> None:
    with pytest.raises(ParameterError, match=r"^path: expected a file or folder name"):
        hevr.read_scan(path)


def test_allow_uneven_must_be_a_bool(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match=r"^allow_uneven: expected True or False, got 'no'"):
        hevr.read_scan(tmp_path, allow_uneven="no")


# -- TIFF -------------------------------------------------------------------------------------
def test_ome_tiff_sizes_in_different_units_and_not_numbers(tmp_path: Path) -> None:
    tifffile = pytest.importorskip("tifffile")
    data = np.zeros((4, 5, 6), np.uint8)
    tifffile.imwrite(
        tmp_path / "mm.tif",
        data,
        ome=True,
        metadata={
            "axes": "ZYX",
            "PhysicalSizeX": 0.5,
            "PhysicalSizeY": 0.25,
            "PhysicalSizeZ": 0.002,
            "PhysicalSizeZUnit": "mm",
        },
    )
    scan = hevr.read_scan(tmp_path / "mm.tif")
    assert scan.spacing == pytest.approx((0.5, 0.25, 2.0)) and scan.details["unit"] == "µm"
    tifffile.imwrite(tmp_path / "bad.tif", data, ome=True, metadata={"axes": "ZYX", "PhysicalSizeX": "abc"})
    with pytest.raises(VolumeFormatError, match=r"^bad\.tif: OME PhysicalSizeX: expected a number, got 'abc'"):
        hevr.read_scan(tmp_path / "bad.tif")  # was silently (1, 1, 1), dropping Y and Z too
    tifffile.imwrite(tmp_path / "ij.tif", data, imagej=True, metadata={"axes": "ZYX", "spacing": "abc"})
    with pytest.raises(VolumeFormatError, match=r"^ij\.tif: ImageJ spacing: expected a number"):
        hevr.read_scan(tmp_path / "ij.tif")


def test_compressed_tiff_larger_than_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tifffile = pytest.importorskip("tifffile")
    tifffile.imwrite(
        tmp_path / "z.tif", np.zeros((3, 400, 400), np.uint8), photometric="minisblack", compression="zlib"
    )
    _small_memory(monkeypatch)
    with pytest.raises(VolumeFormatError, match=r"^z\.tif: too big: 480000 bytes of compressed"):
        hevr.read_scan(tmp_path / "z.tif")


# -- Zarr -------------------------------------------------------------------------------------
def _ome_zarr(path: Path, axes: list[dict], transforms: list[dict], shape: tuple[int, ...] = (4, 5, 6)) -> Path:
    import zarr

    group = zarr.open_group(str(path), mode="w", zarr_format=3)
    group.create_array("0", shape=shape, dtype="i2")
    group.attrs["ome"] = {
        "version": "0.5",
        "multiscales": [{"axes": axes, "datasets": [{"path": "0", "coordinateTransformations": transforms}]}],
    }
    return path


def _space(name: str, unit: str = "micrometer") -> dict:
    return {"name": name, "type": "space", "unit": unit}


def test_ome_zarr_units_and_malformed_scales(tmp_path: Path) -> None:
    axes = [_space("z", "millimeter"), _space("y"), _space("x")]
    scan = hevr.read_scan(_ome_zarr(tmp_path / "mm.zarr", axes, [{"type": "scale", "scale": [0.003, 2, 1]}]))
    assert scan.spacing == pytest.approx((1.0, 2.0, 3.0)) and scan.details["unit"] == "micrometer"
    with pytest.raises(VolumeFormatError, match=r"different units"):
        hevr.read_scan(_ome_zarr(tmp_path / "pc.zarr", [_space("z", "parsec"), _space("y"), _space("x")], []))
    for bad in ([2, 1], ["a", 1, 1], [True, 1, 1], [[1], 1, 1]):  # a short scale was silently ignored
        with pytest.raises(VolumeFormatError, match=r"^b\.zarr: OME-Zarr scale: expected 3 numbers"):
            hevr.read_scan(
                _ome_zarr(tmp_path / "b.zarr", [_space(a) for a in "zyx"], [{"type": "scale", "scale": bad}])
            )


def test_zarr_declaring_more_than_memory(tmp_path: Path) -> None:
    """zarr fills missing chunks: an empty store of 20000**3 voxels tried to allocate 16 TB."""
    import zarr

    zarr.create_array(str(tmp_path / "big.zarr"), shape=(20000,) * 3, chunks=(64,) * 3, dtype="i2")
    with pytest.raises(VolumeFormatError, match=r"^big\.zarr: too big: 16000000000000 bytes of Zarr data"):
        hevr.read_scan(tmp_path / "big.zarr")
    _ome_zarr(tmp_path / "ome.zarr", [_space(a) for a in "zyx"], [], shape=(20000,) * 3)
    with pytest.raises(VolumeFormatError, match=r"^ome\.zarr: too big"):
        hevr.read_scan(tmp_path / "ome.zarr")
