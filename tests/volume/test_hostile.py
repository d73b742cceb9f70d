"""hevr.load_volume on hostile files: each ends in VolumeFormatError (or MissingFileError)
naming the file and the field, within a second and a few MB — no hang, no zip bomb, no
escaping ValueError/OSError."""

from __future__ import annotations

import gzip
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import hevr

SECONDS = 1.0
PEAK_BYTES = 4 << 20


def refused(error: type[Exception], fn: Callable[..., Any], *args: Any, **kwargs: Any) -> str:
    """``fn`` must raise ``error`` within SECONDS and PEAK_BYTES; returns the message."""
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(error) as info:
            fn(*args, **kwargs)
        seconds, peak = time.perf_counter() - t0, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert seconds < SECONDS, seconds
    assert peak < PEAK_BYTES, peak
    return str(info.value)


def header(sizes: str = "2 2 2", encoding: str = "raw", **fields: str) -> bytes:
    lines = ["NRRD0004", "type: uint8", "dimension: 3", f"sizes: {sizes}", f"encoding: {encoding}"]
    lines += [f"{k.replace('_', ' ')}: {v}" for k, v in fields.items()]
    return ("\n".join(lines) + "\n\n").encode("utf-8")


# -- .raw names -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, data",
    [
        ("a_0x5x5_uint8.raw", b""),
        ("b_5x0x5_uint8.raw", b"x" * 10),
        ("c_5x5x0_int16.raw", b""),
        ("d_0x0x0_float32.raw", b""),
    ],
)
def test_raw_name_with_a_zero_size(tmp_path: Path, name: str, data: bytes) -> None:
    (tmp_path / name).write_bytes(data)
    msg = refused(hevr.VolumeFormatError, hevr.load_volume, tmp_path / name)
    assert msg.startswith(f"{name}: shape: expected positive sizes in the name's XxYxZ token, got ")
    assert "shape=(nz, ny, nx)" in msg


def test_raw_name_with_absurd_sizes(tmp_path: Path) -> None:
    name = "e_" + "9" * 100 + "x5x5_uint8.raw"
    (tmp_path / name).write_bytes(b"x")
    assert "truncated" in refused(hevr.VolumeFormatError, hevr.load_volume, tmp_path / name)


def test_raw_name_with_zero_size_but_explicit_shape_loads(tmp_path: Path) -> None:
    (tmp_path / "a_0x5x5_uint8.raw").write_bytes(bytes(8))
    vol, _ = hevr.load_volume(tmp_path / "a_0x5x5_uint8.raw", shape=(2, 2, 2))
    assert vol.shape == (2, 2, 2)


# -- NRRD -------------------------------------------------------------------------------------
def test_gzip_bomb_is_not_decompressed(tmp_path: Path) -> None:
    path = tmp_path / "bomb.nrrd"
    path.write_bytes(header(encoding="gzip") + gzip.compress(bytes(64 << 20)))  # 64 MiB for 8 bytes
    msg = refused(hevr.VolumeFormatError, hevr.load_volume, path)
    assert msg.startswith("bomb.nrrd: size mismatch") and "more than 8" in msg


def test_gzip_sizes_beyond_memory_are_refused_before_reading(tmp_path: Path) -> None:
    path = tmp_path / "big.nrrd"
    path.write_bytes(header("1000000 1000000 1000000", encoding="gzip") + gzip.compress(bytes(1 << 20)))
    msg = refused(hevr.VolumeFormatError, hevr.load_volume, path)
    assert msg.startswith("big.nrrd: too big") and "memory" in msg


def test_gzip_byte_skip_beyond_the_data(tmp_path: Path) -> None:
    path = tmp_path / "skip.nrrd"
    path.write_bytes(header(encoding="gzip", byte_skip="10000000000000") + gzip.compress(bytes(16)))
    assert "'byte skip': expected at most" in refused(hevr.VolumeFormatError, hevr.load_volume, path)


def test_gzip_byte_skip_is_capped_before_decompressing(tmp_path: Path) -> None:
    """A 4 GiB skip over a small bomb used to decompress for seconds before failing."""
    path = tmp_path / "skip.nrrd"
    path.write_bytes(header(encoding="gzip", byte_skip=str(1 << 32)) + gzip.compress(bytes(1 << 20)))
    assert "'byte skip': expected at most" in refused(hevr.VolumeFormatError, hevr.load_volume, path)


def test_gzip_small_byte_skip_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "ok.nrrd"
    path.write_bytes(header(encoding="gzip", byte_skip="5") + gzip.compress(b"HEAD!" + bytes(range(8))))
    vol, _ = hevr.load_volume(path)
    assert vol.ravel().tolist() == list(range(8))


@pytest.mark.parametrize("line_skip", ["1000000000000", "99999999999999999999"])
def test_huge_line_skip_does_not_hang(tmp_path: Path, line_skip: str) -> None:
    path = tmp_path / "ls.nrrd"
    path.write_bytes(header(line_skip=line_skip) + b"a\nb\n" + bytes(8))
    assert "truncated" in refused(hevr.VolumeFormatError, hevr.load_volume, path)


def test_line_skip_over_data_without_newlines_is_bounded(tmp_path: Path) -> None:
    path = tmp_path / "nl.nrrd"
    path.write_bytes(header(line_skip="1") + bytes(32 << 20))
    assert "truncated" in refused(hevr.VolumeFormatError, hevr.load_volume, path)


@pytest.mark.parametrize(
    "sizes, needle",
    [
        ("1000000 1000000 1000000", "truncated"),
        ("٢ 2 2", "'sizes'"),
        ("2_0 2 2", "'sizes'"),
        ("2 2 -2", "positive"),
        ("0 2 2", "positive"),
        ("9" * 5000 + " 2 2", "'sizes'"),
    ],
)
def test_bad_sizes(tmp_path: Path, sizes: str, needle: str) -> None:
    path = tmp_path / "s.nrrd"
    path.write_bytes(header(sizes) + bytes(8))
    msg = refused(hevr.VolumeFormatError, hevr.load_volume, path)
    assert msg.startswith("s.nrrd:") and needle in msg


@pytest.mark.parametrize(
    "fields",
    [
        {"spacings": "-1 1 1"},
        {"spacings": "inf 1 1"},
        {"spacings": "0 1 1"},
        {"space_directions": "(0,0,0) (0,1,0) (0,0,1)"},
        {"space_directions": "(nan,0,0) (0,1,0) (0,0,1)"},
        {"space_directions": "(inf,0,0) (0,1,0) (0,0,1)"},
    ],
)
def test_bad_spacing(tmp_path: Path, fields: dict) -> None:
    path = tmp_path / "sp.nrrd"
    path.write_bytes(header(**fields) + bytes(8))
    assert "spacing" in refused(hevr.VolumeFormatError, hevr.load_volume, path)


@pytest.mark.parametrize("data_file", ["a\0b", "x" * 5000, "/dev/zero", "."])
def test_unusable_data_file_names(tmp_path: Path, data_file: str) -> None:
    path = tmp_path / "df.nhdr"
    path.write_bytes(header(data_file=data_file))
    # a device or a folder exists but is no file to read (reading /dev/zero would never end)
    error = hevr.NotRegularFileError if data_file in ("/dev/zero", ".") else hevr.MissingFileError
    assert refused(error, hevr.load_volume, path).startswith("path: expected a volume file")


@pytest.mark.parametrize("name", ["x" * 300 + ".npy", "a\0b.nrrd"])
def test_unusable_volume_names(tmp_path: Path, name: str) -> None:
    msg = refused(hevr.MissingFileError, hevr.load_volume, str(tmp_path) + "/" + name)
    assert msg.startswith("path: expected a volume file")


def test_nan_spacing_override(tmp_path: Path) -> None:
    hevr.save_volume(tmp_path / "v.npy", np.zeros((2, 2, 2), np.uint8))
    msg = refused(hevr.ParameterError, hevr.load_volume, tmp_path / "v.npy", spacing=(float("nan"), 1, 1))
    assert msg.startswith("spacing: expected")


# -- DICOM ------------------------------------------------------------------------------------
def _dicom_slice(path: Path, k: int, pixel_spacing: list[float]) -> None:
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = CTImageStorage, generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
    ds.SeriesInstanceUID, ds.Modality = "1.2.3", "CT"
    ds.Rows, ds.Columns, ds.SamplesPerPixel, ds.PhotometricInterpretation = 2, 3, 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
    ds.PixelSpacing = pixel_spacing
    ds.ImagePositionPatient, ds.ImageOrientationPatient = [0, 0, 2.0 * k], [1, 0, 0, 0, 1, 0]
    ds.PixelData = np.zeros((2, 3), "<i2").tobytes()
    ds.save_as(path, enforce_file_format=True)


@pytest.mark.parametrize("pixel_spacing", [[-0.5, 0.7], [0.0, 0.7]])
def test_dicom_non_positive_pixel_spacing(tmp_path: Path, pixel_spacing: list[float]) -> None:
    pytest.importorskip("pydicom")
    (tmp_path / "ct").mkdir()
    for k in range(3):
        _dicom_slice(tmp_path / "ct" / f"{k}.dcm", k, pixel_spacing)
    with pytest.raises(hevr.VolumeFormatError, match="^ct: spacing: expected 3 positive finite"):
        hevr.load_volume(tmp_path / "ct")
    assert hevr.load_volume(tmp_path / "ct", spacing=(1, 1, 1))[1] == (1.0, 1.0, 1.0)  # an override is fine
