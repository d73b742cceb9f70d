"""Tests for choosing DICOM series: several series, listings, folder trees, DICOMDIR, single files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_dicom import dataset, write_series, write_slice

import hevr
from hevr.errors import VolumeFormatError
from hevr.volume.dicom import SeriesInfo, list_series, read_dicom
from hevr.volume.dicom_series import scan_images

pytest.importorskip("pydicom")

CT_UID, MR_UID = "1.2.826.0.1.3680043.2.1125.1.11", "1.2.826.0.1.3680043.2.1125.2.22"


def _two_series(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """A CT series of 4 slices 3x5 in ``folder/ct/a`` and an MR series of 3 slices 2x4 in ``folder/mr``."""
    ct = np.arange(4 * 3 * 5, dtype=np.int16).reshape(4, 3, 5)
    mr = 100 + np.arange(3 * 2 * 4, dtype=np.int16).reshape(3, 2, 4)
    write_series(folder / "ct" / "a", ct, series=CT_UID, SeriesNumber=2, SeriesDescription="AX 2.5")
    write_series(
        folder / "mr", mr, series=MR_UID, gap=4.0, intercept=0, modality="MR", SeriesNumber=7, SeriesDescription="T1 AX"
    )
    return ct, mr


def test_several_series_refused_with_listing(tmp_path: Path) -> None:
    _two_series(tmp_path / "cd")
    with pytest.raises(VolumeFormatError) as info:
        read_dicom(tmp_path / "cd")
    msg = str(info.value)
    assert msg.startswith("cd: expected one DICOM series, found 2") and "series=UID" in msg and "--series UID" in msg
    lines = msg.splitlines()[1:]
    assert len(lines) == 2
    assert lines[0].strip().startswith(CT_UID) and "#2 CT 'AX 2.5': 4 images, 3x5" in lines[0]
    assert lines[1].strip().startswith(MR_UID) and "#7 MR 'T1 AX': 3 images, 2x4" in lines[1]
    with pytest.raises(VolumeFormatError) as info:  # the loader passes the listing on
        hevr.load_volume(tmp_path / "cd")
    assert MR_UID in str(info.value)


@pytest.mark.parametrize("choice", ["uid", "number", "prefix"])
def test_each_series_chosen(tmp_path: Path, choice: str) -> None:
    ct, mr = _two_series(tmp_path / "cd")
    for uid, number, stored, modality, intercept in ((CT_UID, "2", ct, "CT", -1024), (MR_UID, "7", mr, "MR", 0)):
        series = {"uid": uid, "number": number, "prefix": uid[:-3]}[choice]
        scan = read_dicom(tmp_path / "cd", series=series)
        np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1] + intercept)
        assert scan.modality == modality and scan.details["series_uid"] == uid
        assert scan.details["series_number"] == number


def test_series_choice_errors(tmp_path: Path) -> None:
    _two_series(tmp_path / "cd")
    with pytest.raises(VolumeFormatError, match=r"series='9\.9' matches no series.*\n.*" + CT_UID):
        read_dicom(tmp_path / "cd", series="9.9")
    with pytest.raises(VolumeFormatError, match=r"series='1\.2\.826' matches 2 series"):
        read_dicom(tmp_path / "cd", series="1.2.826")  # a prefix of both


def test_list_series(tmp_path: Path) -> None:
    _two_series(tmp_path / "cd")
    (tmp_path / "cd" / "notes.txt").write_text("report")
    (tmp_path / "cd" / ".hidden").mkdir()
    write_slice(
        tmp_path / "cd" / ".hidden" / "x.dcm",
        np.zeros((3, 5), np.int16),
        position=[0, 0, 0],
        instance=1,
        series="7.7.7",
    )  # hidden folders are skipped
    infos = list_series(tmp_path / "cd")
    assert [i.uid for i in infos] == [CT_UID, MR_UID]
    ct = infos[0]
    assert isinstance(ct, SeriesInfo)
    assert (ct.number, ct.modality, ct.description, ct.images, ct.frames, ct.rows, ct.columns) == (
        2,
        "CT",
        "AX 2.5",
        4,
        4,
        3,
        5,
    )
    assert ct.path.parent == tmp_path / "cd" / "ct" / "a"
    assert ct.summary() == f"{CT_UID}  #2 CT 'AX 2.5': 4 images, 3x5, in {tmp_path / 'cd' / 'ct' / 'a'}"
    with pytest.raises(AttributeError):
        ct.uid = "x"  # type: ignore[misc]  # frozen


def test_recursive_folder_and_single_file(tmp_path: Path) -> None:
    stored = np.arange(3 * 2 * 4, dtype=np.int16).reshape(3, 2, 4)
    paths = write_series(tmp_path / "patient" / "study" / "series", stored, series="5.5")
    (tmp_path / "patient" / "DICOMDIR.txt").write_text("not DICOM")
    expected = stored[:, ::-1, ::-1] - 1024
    np.testing.assert_array_equal(read_dicom(tmp_path / "patient").volume, expected)
    # A single slice stands for its series in its folder, as viewers do; other series there are ignored.
    write_slice(
        paths[0].parent / "other.dcm", np.zeros((2, 4), np.int16), position=[0, 0, 50], instance=1, series="6.6"
    )
    scan = read_dicom(paths[1])
    np.testing.assert_array_equal(scan.volume, expected)
    assert scan.details["images"] == 3


def _fileset_dataset(pixels: np.ndarray, series: str, z: float, number: int) -> object:
    return dataset(
        pixels,
        series=series,
        PatientID="P1",
        PatientName="Test^Patient",
        StudyInstanceUID="1.2.9",
        StudyDate="20240101",
        StudyTime="120000",
        StudyID="1",
        SeriesNumber=number,
        InstanceNumber=int(z) + 1,
        ImagePositionPatient=[0.0, 0.0, z],
        ImageOrientationPatient=[1, 0, 0, 0, 1, 0],
        PixelSpacing=[0.5, 0.5],
    )


def test_dicomdir_written_by_pydicom(tmp_path: Path) -> None:
    from pydicom.fileset import FileSet

    stored = np.arange(3 * 2 * 2, dtype=np.int16).reshape(3, 2, 2)
    fs = FileSet()
    for z in (2, 0, 1):
        fs.add(_fileset_dataset(stored[z], "3.3.3", float(z), 1))
    fs.add(_fileset_dataset(np.zeros((2, 2), np.int16), "4.4.4", 0.0, 2))
    fs.write(tmp_path / "cd")
    (tmp_path / "cd" / "stray.dcm").write_bytes(b"x")  # not referenced: the DICOMDIR decides
    infos = list_series(tmp_path / "cd" / "DICOMDIR")
    assert sorted((i.uid, i.images) for i in infos) == [("3.3.3", 3), ("4.4.4", 1)]
    with pytest.raises(VolumeFormatError, match=r"DICOMDIR: expected one DICOM series, found 2"):
        read_dicom(tmp_path / "cd" / "DICOMDIR")
    scan = read_dicom(tmp_path / "cd" / "DICOMDIR", series="3.3.3")
    np.testing.assert_array_equal(scan.volume, stored[:, ::-1, ::-1])
    assert scan.spacing == pytest.approx((0.5, 0.5, 1.0))
    # The folder holding the DICOMDIR gives the same series (the index itself has no image).
    np.testing.assert_array_equal(read_dicom(tmp_path / "cd", series="1").volume, scan.volume)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "DICOMDIR").write_bytes(b"junk")
    with pytest.raises(VolumeFormatError, match=r"^DICOMDIR: expected a DICOMDIR"):
        read_dicom(tmp_path / "bad" / "DICOMDIR")


def test_pydicom_bundled_dicomdir() -> None:
    """pydicom ships a real DICOMDIR (dcmmkdir) of 3 patients with 13 series of 16x16 images."""
    from pydicom.data import get_testdata_file

    path = get_testdata_file("DICOMDIR", download=False)
    assert path is not None  # bundled with pydicom itself, no network
    infos = list_series(path)
    assert len(infos) == 13 and {i.modality for i in infos} == {"CR", "CT", "MR"}
    assert all((i.rows, i.columns) == (16, 16) for i in infos)
    with pytest.raises(VolumeFormatError, match=r"found 13;.*series=UID"):
        read_dicom(path)
    by_images = {i.images: i for i in infos if i.modality == "CT"}
    # The 5-slice CT series: slices 2.5 mm apart, stored head first (z descending).
    scan = read_dicom(path, series=by_images[5].uid)
    assert scan.volume.shape == (5, 16, 16) and scan.spacing == pytest.approx((0.488281, 0.488281, 2.5))
    assert scan.origin[2] == pytest.approx(-1.2375)
    # The 4-slice CT series has a gap of 202.5 mm before its last 3 slices (1.25 mm apart).
    with pytest.raises(VolumeFormatError, match=r"uneven slice spacing.*202\.5 mm"):
        read_dicom(path, series=by_images[4].uid)
    assert read_dicom(path, series=by_images[4].uid, allow_uneven=True).details["uneven_spacing"] is True
    localizer = next(i for i in infos if i.modality == "MR" and i.images == 3)
    with pytest.raises(VolumeFormatError, match="ImageOrientationPatient.*localizer"):
        read_dicom(path, series=localizer.uid)


def test_one_file_repeated_in_other_syntaxes_is_one_slice(capsys, caplog):
    """pydicom's MR_small.dcm beside eight copies of itself in other transfer syntaxes (same
    SOPInstanceUID): one slice, read from the named file, and none of the siblings' warnings
    (issue 29, item 3)."""
    import warnings

    pytest.importorskip("pydicom")
    from pydicom.data import get_testdata_file

    path = Path(get_testdata_file("MR_small.dcm", download=False))
    assert len([f for f in path.parent.glob("MR_small*.dcm")]) > 3  # the copies are there
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        images = scan_images(path)
    assert [im.path.name for im in images] == ["MR_small.dcm"]
    assert not seen, [str(w.message) for w in seen]
    scan = hevr.read_scan(path)
    assert scan.volume.shape == (1, 64, 64)


def test_one_file_reads_its_series_whatever_else_lies_beside_it(tmp_path: Path, caplog) -> None:
    """A file argument means that file's series (issue 29, item 3): beside it a damaged file,
    a file of another series whose pixel data would be a decompression bomb (a header that
    declares 60000 x 60000 pixels) and a duplicate of one of its slices (same SOPInstanceUID)
    change nothing, and nothing about them is said above DEBUG."""
    import logging
    import warnings

    ct = np.arange(3 * 3 * 5, dtype=np.int16).reshape(3, 3, 5)
    paths = write_series(tmp_path, ct, series=CT_UID)
    whole = read_dicom(tmp_path)
    broken = bytearray(paths[0].read_bytes())
    assert broken[128:138] == b"DICM\x02\x00\x00\x00UL"  # (0002,0000) UL, the first element
    broken[138:140] = b"\x06\x00"  # its length: 6 bytes for a UL (4 bytes each), which pydicom cannot parse
    (tmp_path / "broken.dcm").write_bytes(broken)
    bomb = dataset(np.zeros((2, 2), np.int16), series=MR_UID, modality="MR")
    bomb.Rows = bomb.Columns = 60000
    bomb.save_as(tmp_path / "bomb.dcm", enforce_file_format=True)
    (tmp_path / "again.dcm").write_bytes(paths[1].read_bytes())
    with caplog.at_level(logging.INFO, logger="hevr"), warnings.catch_warnings():
        warnings.simplefilter("error")
        scan = read_dicom(paths[0])
    assert np.array_equal(scan.volume, whole.volume) and scan.details["images"] == 3
    said = " ".join(r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
    print("LOG", caplog.text, caplog.records)
    assert not said, said
    assert "broken" not in caplog.text and "bomb" not in caplog.text
    with pytest.raises(VolumeFormatError, match="found 2"):  # the folder itself: both series, listed
        read_dicom(tmp_path)
