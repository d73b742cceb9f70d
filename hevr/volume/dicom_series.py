"""Finding DICOM series: folders (recursive), DICOMDIR files and single files (needs pydicom).

A radiologist's export is a folder tree (often a CD with a ``DICOMDIR`` index) holding
several series of several studies. This module reads only the headers
(``stop_before_pixels=True``), groups the images by ``SeriesInstanceUID`` and picks the one
series to read; :mod:`hevr.volume.dicom` then decodes the pixels of that series alone.

What is an image
----------------
A file that pydicom reads as DICOM (``DICM`` after the 128-byte preamble) and that has
``Rows`` and ``Columns``. Anything else (text files, DICOMDIR indexes, structured reports,
presentation states, hidden files and folders) is skipped quietly; a DICOM file that fails
to parse is skipped with a warning (a missing slice then shows up as a gap when its series
is read).

Choosing a series
-----------------
``series=`` is matched, in this order, as the exact ``SeriesInstanceUID``, as a
``SeriesNumber`` (``"3"``) if exactly one series has it, or as a prefix of exactly one
``SeriesInstanceUID``. Without it a path holding several series is refused with a listing
of them (:class:`SeriesInfo`), so that the owner chooses knowingly.
"""

from __future__ import annotations

import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.files import require_file
from ..errors import MissingDependencyError, VolumeFormatError
from ._optional import require
from .dicom_mosaic import is_mosaic, mosaic_of

__all__ = ["Image", "SeriesInfo", "choose_series", "group_series", "list_series", "scan_images"]

_log = logging.getLogger(__name__)

_DICOMDIR_CLASS = "1.2.840.10008.1.3.10"  # Media Storage Directory Storage


@dataclass(frozen=True)
class Image:
    """One DICOM file with pixel data: its path and its header (no pixel data)."""

    path: Path
    header: Any  # pydicom.Dataset read with stop_before_pixels=True

    @property
    def series_uid(self) -> str:
        return str(self.header.get("SeriesInstanceUID", "") or "")

    @property
    def instance_uid(self) -> str:
        """SOPInstanceUID: the same image saved again (another transfer syntax) keeps it."""
        return str(self.header.get("SOPInstanceUID", "") or "")

    @property
    def frames(self) -> int:
        try:
            return max(1, int(self.header.get("NumberOfFrames") or 1))
        except (TypeError, ValueError):
            raise VolumeFormatError(
                f"{self.path.name}: NumberOfFrames: expected a positive integer, got "
                f"{str(self.header.get('NumberOfFrames'))[:40]!r}"
            ) from None


@dataclass(frozen=True)
class SeriesInfo:
    """What the headers say about one series (for listings; nothing from the pixels).

    Attributes
    ----------
    uid : str
        SeriesInstanceUID (``""`` when the files have none).
    number : int or None
        SeriesNumber.
    modality, description : str
        Modality (``"CT"``, ``"MR"``, …) and SeriesDescription (``""`` when absent).
    images, frames : int
        Files, and frames in them (more than files for multi-frame files).
    rows, columns : int
        Image size of the first file.
    path : pathlib.Path
        The first file (its folder is where the series lies).
    """

    uid: str
    number: int | None
    modality: str
    description: str
    images: int
    frames: int
    rows: int
    columns: int
    path: Path

    def summary(self) -> str:
        """One line: UID, number, modality, description, counts, size and folder.

        >>> SeriesInfo("1.2.3", 4, "CT", "AX 2.5", 120, 120, 512, 512, Path("cd/S4/IM1")).summary()
        "1.2.3  #4 CT 'AX 2.5': 120 images, 512x512, in cd/S4"
        """
        count = f"{self.images} image{'s' * (self.images != 1)}"
        if self.frames != self.images:
            count += f" ({self.frames} frames)"
        number = "-" if self.number is None else str(self.number)
        return (
            f"{self.uid or '(no SeriesInstanceUID)'}  #{number} {self.modality or '?'} {self.description!r}: "
            f"{count}, {self.rows}x{self.columns}, in {self.path.parent}"
        )


def _read_header(pydicom: Any, f: Path, *, quiet: bool, named: bool = True) -> Any | None:
    """The header of ``f``, or None when it is not DICOM (quiet) or cannot be parsed (warned;
    for a file the user did not name, a sibling of the file named, only logged at DEBUG)."""
    from pydicom.errors import InvalidDicomError

    try:
        return pydicom.dcmread(f, stop_before_pixels=True)
    except InvalidDicomError:
        _log.debug("skipping %s: not a DICOM file", f)
    except Exception as exc:  # noqa: BLE001  # truncated or damaged files: pydicom raises many types
        if not quiet:
            raise VolumeFormatError(f"{f.name}: cannot read the DICOM file ({exc})") from None
        _log.log(logging.WARNING if named else logging.DEBUG, "skipping %s: cannot read it as DICOM (%s)", f, exc)
    return None


def _is_image(ds: Any) -> bool:
    meta = getattr(ds, "file_meta", None) or {}
    if str(meta.get("MediaStorageSOPClassUID", "")) == _DICOMDIR_CLASS or "DirectoryRecordSequence" in ds:
        return False
    return "Rows" in ds and "Columns" in ds


def _walk(folder: Path) -> list[Path]:
    """Every non-hidden regular file under ``folder``, sorted, without following links to
    folders; a FIFO, socket or device is skipped (opening it to look for DICOM would block)."""
    out = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for f in sorted(files):
            if f.startswith("."):
                continue
            if (Path(root) / f).is_file():
                out.append(Path(root) / f)
            else:
                _log.warning("skipping %s: not a regular file (a FIFO, socket or device)", Path(root) / f)
    return out


def _dicomdir_files(pydicom: Any, path: Path) -> list[Path]:
    """The files a DICOMDIR references (those that exist; missing ones are warned about)."""
    from pydicom.fileset import FileSet

    try:
        fs = FileSet(pydicom.dcmread(path))
        files = [Path(inst.path) for inst in fs]
    except Exception as exc:  # noqa: BLE001  # pydicom raises ValueError, InvalidDicomError, KeyError, ...
        raise VolumeFormatError(
            f"{path.name}: expected a DICOMDIR (a DICOM file-set index), cannot read it ({exc})"
        ) from None
    missing = [f for f in files if not f.is_file()]
    if missing:
        _log.warning("%s: %d referenced file(s) are missing, e.g. %s", path.name, len(missing), missing[0])
    return [f for f in files if f.is_file()]


def scan_images(path: Path) -> list[Image]:
    """The DICOM images a folder (recursively), a DICOMDIR or a single file stands for.

    A single-frame file stands for its whole series: the files of the same series in the
    same folder (not below it), as viewers do; the other files' warnings are not shown. A
    multi-frame file is a series by itself. A file that repeats an image (same
    SOPInstanceUID, e.g. another transfer syntax) is not a second slice.
    """
    pydicom = require("pydicom", path)
    path = require_file(path, "path", "a DICOM folder, DICOMDIR or DICOM file")
    if path.is_dir():
        return _distinct(path.name, _images(pydicom, _walk(path), quiet=True))
    if path.name.upper() == "DICOMDIR":
        return _distinct(path.name, _images(pydicom, _dicomdir_files(pydicom, path), quiet=True))
    ds = _read_header(pydicom, path, quiet=False)
    if ds is not None and "DirectoryRecordSequence" in ds:
        return _distinct(path.name, _images(pydicom, _dicomdir_files(pydicom, path), quiet=True))
    if ds is None or not _is_image(ds):
        raise VolumeFormatError(
            f"{path.name}: expected a DICOM image file (or a folder or DICOMDIR), got "
            f"{'no DICOM file' if ds is None else 'a DICOM file without an image'}"
        )
    one = Image(path, ds)
    if one.frames > 1 or is_mosaic(ds):  # a volume by itself
        return [one]
    uid = one.series_uid
    siblings = [f for f in sorted(path.parent.iterdir()) if f.is_file() and not f.name.startswith(".") and f != path]
    with warnings.catch_warnings():  # files the user did not name: their readers' complaints are not theirs
        warnings.simplefilter("ignore")
        found = _images(pydicom, siblings, quiet=True, named=False)
    images = _distinct(path.name, [one] + [im for im in found if im.series_uid == uid and im.frames == 1])
    if len(images) > 1:
        _log.info(
            "%s: one slice of series %s; reading its %d files in %s", path.name, uid or "?", len(images), path.parent
        )
    return images


def _distinct(name: str, images: list[Image]) -> list[Image]:
    """``images`` without the repeats of an image already in the list (same SOPInstanceUID: one
    slice saved again, e.g. in another transfer syntax), the first kept: a named file first."""
    seen: set[str] = set()
    out = []
    for im in images:
        uid = im.instance_uid
        if uid and uid in seen:
            continue
        seen.add(uid)
        out.append(im)
    if len(out) < len(images):
        _log.info(
            "%s: %d file(s) repeat an image already read (same SOPInstanceUID): not read twice",
            name,
            len(images) - len(out),
        )
    return out


def _images(pydicom: Any, files: list[Path], *, quiet: bool, named: bool = True) -> list[Image]:
    out = []
    for f in files:
        ds = _read_header(pydicom, f, quiet=quiet, named=named)
        if ds is not None and _is_image(ds):
            out.append(Image(f, ds))
    return out


def group_series(images: list[Image]) -> dict[str, list[Image]]:
    """Images by SeriesInstanceUID, in order of first appearance."""
    groups: dict[str, list[Image]] = {}
    for im in images:
        groups.setdefault(im.series_uid, []).append(im)
    return groups


def _info(uid: str, images: list[Image]) -> SeriesInfo:
    ds = images[0].header
    try:
        number: int | None = int(ds.get("SeriesNumber"))
    except (TypeError, ValueError):
        number = None
    frames, rows, cols = sum(im.frames for im in images), int(ds.get("Rows") or 0), int(ds.get("Columns") or 0)
    try:  # a Siemens MOSAIC: its slices and their size (a damaged one, or one without nibabel to read its
        mosaic = mosaic_of(ds, images[0].path)  # header, is listed as stored; reading it says why)
    except (VolumeFormatError, MissingDependencyError):
        mosaic = None
    if mosaic is not None:
        frames, rows, cols = len(images) * mosaic.slices, mosaic.rows, mosaic.columns
    return SeriesInfo(
        uid=uid,
        number=number,
        modality=str(ds.get("Modality", "") or ""),
        description=str(ds.get("SeriesDescription", "") or ""),
        images=len(images),
        frames=frames,
        rows=rows,
        columns=cols,
        path=images[0].path,
    )


def list_series(path: str | os.PathLike[str]) -> list[SeriesInfo]:
    """The image series under ``path`` (a folder, a DICOMDIR or a DICOM file), from headers only.

    Parameters
    ----------
    path : str or os.PathLike
        A folder (searched recursively), a ``DICOMDIR`` file, or one DICOM file.

    Returns
    -------
    list of SeriesInfo
        One per SeriesInstanceUID, in the order their first file was found.

    Raises
    ------
    MissingFileError
        ``path`` does not exist.
    VolumeFormatError
        A DICOMDIR or single file that cannot be read.
    MissingDependencyError
        pydicom is not installed.
    """
    return [_info(uid, ims) for uid, ims in group_series(scan_images(Path(path))).items()]


def _listing(groups: dict[str, list[Image]]) -> str:
    return "\n".join(f"  {_info(uid, ims).summary()}" for uid, ims in groups.items())


def choose_series(name: str, images: list[Image], series: str | None) -> tuple[str, list[Image]]:
    """The UID and images of the one series to read (see the module docstring)."""
    groups = group_series(images)
    if not groups:
        raise VolumeFormatError(f"{name}: expected DICOM images, found no DICOM file with pixel data in it")
    how = "pass series=UID (CLI --series UID; a SeriesNumber or a unique UID prefix also works)"
    if series is None:
        if len(groups) == 1:
            uid = next(iter(groups))
            return uid, groups[uid]
        raise VolumeFormatError(f"{name}: expected one DICOM series, found {len(groups)}; {how}:\n{_listing(groups)}")
    wanted = str(series).strip()
    if wanted in groups:
        return wanted, groups[wanted]
    by_number = {u: g for u, g in groups.items() if str(g[0].header.get("SeriesNumber", "")).strip() == wanted}
    by_prefix = {u: g for u, g in groups.items() if wanted and u.startswith(wanted)}
    for matches in (by_number, by_prefix):
        if len(matches) == 1:
            uid = next(iter(matches))
            return uid, matches[uid]
    matches = by_number or by_prefix
    what = f"matches {len(matches)} series" if matches else "matches no series"
    raise VolumeFormatError(
        f"{name}: series={wanted!r} {what}; expected a SeriesInstanceUID, SeriesNumber "
        f"or unique UID prefix of one of:\n{_listing(matches or groups)}"
    )
