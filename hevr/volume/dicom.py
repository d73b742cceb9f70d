"""DICOM series folders (needs pydicom, the ``hevr[io]`` extra)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import VolumeFormatError
from ._optional import require
from .rescale import rescale

__all__ = ["read_dicom_folder"]

_log = logging.getLogger(__name__)

_Spacing = tuple[float, float, float]


def read_dicom_folder(folder: Path) -> tuple[np.ndarray, _Spacing]:
    pydicom = require("pydicom", folder)
    from pydicom.errors import InvalidDicomError

    slices = []
    for f in sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")):
        try:
            ds = pydicom.dcmread(f)
        except InvalidDicomError:
            _log.debug("%s: skipping %s, not a DICOM file", folder.name, f.name)
            continue
        except Exception as exc:
            raise VolumeFormatError(f"{f.name}: cannot read DICOM file in {folder} ({exc})") from None
        if "PixelData" in ds:  # DICOMDIR and other non-image objects carry none
            slices.append((f, ds))
    if not slices:
        raise VolumeFormatError(f"{folder.name}: expected a folder of DICOM slices, found no "
                                "DICOM file with pixel data in it")
    first = slices[0][1]
    series = sorted({str(ds.get("SeriesInstanceUID", "?")) for _, ds in slices})
    if len(series) > 1:
        raise VolumeFormatError(f"{folder.name}: expected one DICOM series, the folder holds "
                                f"{len(series)} ({', '.join(series[:4])}); split them into folders")
    for f, ds in slices:
        if _dicom_number(f, ds, "NumberOfFrames", 1) > 1 or _dicom_number(f, ds, "SamplesPerPixel", 1) != 1:
            raise VolumeFormatError(f"{f.name}: expected single-frame greyscale DICOM slices, got "
                                    f"{ds.get('NumberOfFrames', 1)} frame(s) with "
                                    f"{ds.get('SamplesPerPixel', 1)} sample(s) per pixel")
        if (ds.get("Rows"), ds.get("Columns")) != (first.get("Rows"), first.get("Columns")):
            raise VolumeFormatError(f"{f.name}: slice size {ds.get('Rows')}x{ds.get('Columns')} differs "
                                    f"from {first.get('Rows')}x{first.get('Columns')} in {slices[0][0].name}")
    order, sz = _dicom_order(folder, slices)
    slices = [slices[i] for i in order]
    pixels = []
    for f, ds in slices:
        try:
            pixels.append(ds.pixel_array)
        except Exception as exc:  # compressed syntaxes need handlers that may be missing
            raise VolumeFormatError(f"{f.name}: cannot decode the pixel data (transfer syntax "
                                    f"{ds.file_meta.get('TransferSyntaxUID', '?')}): {exc}") from None
    slopes = [_dicom_number(f, ds, "RescaleSlope", 1) for f, ds in slices]
    inters = [_dicom_number(f, ds, "RescaleIntercept", 0) for f, ds in slices]
    vol = rescale(np.stack(pixels), slopes, inters)
    ps = first.get("PixelSpacing")
    if ps is None or len(ps) != 2:
        _log.warning("%s: no PixelSpacing; assuming 1 x 1", folder.name)
        ps = (1.0, 1.0)
    # PixelSpacing is (between rows, between columns) = (sy, sx).
    try:
        return vol, (float(ps[1]), float(ps[0]), sz)
    except (TypeError, ValueError):
        raise VolumeFormatError(f"{folder.name}: PixelSpacing: expected two numbers, got {ps!r}") from None


def _dicom_number(f: Path, ds: Any, key: str, default: float) -> float:
    """A numeric DICOM attribute (``default`` when absent, empty or 0), else VolumeFormatError."""
    value = ds.get(key, default)
    try:
        return float(value or default)
    except (TypeError, ValueError):
        raise VolumeFormatError(f"{f.name}: {key}: expected a number, got {str(value)[:40]!r}") from None


def _dicom_order(folder: Path, slices: list) -> tuple[np.ndarray, float]:
    """Slice order (ascending along the slice normal) and the z spacing."""
    try:
        iop = np.array(slices[0][1].ImageOrientationPatient, dtype=np.float64)
        normal = np.cross(iop[:3], iop[3:])
        pos = np.array([float(np.dot(np.array(ds.ImagePositionPatient, np.float64), normal))
                        for _, ds in slices])
    except (AttributeError, TypeError, ValueError):
        pos = None
    if pos is not None:
        order = np.argsort(pos, kind="stable")
        gaps = np.diff(pos[order])
        if len(gaps) and gaps.min() < 1e-4:
            i = int(np.argmin(gaps))
            raise VolumeFormatError(
                f"{folder.name}: slices {slices[order[i]][0].name} and {slices[order[i + 1]][0].name} "
                f"lie at the same position {pos[order[i]]:.4g}; expected one slice per position")
        if len(gaps):
            sz = float(np.median(gaps))
            if gaps.max() - gaps.min() > 1e-3 * sz:
                _log.warning("%s: uneven slice spacing %.4g..%.4g; using the median %.4g",
                             folder.name, gaps.min(), gaps.max(), sz)
            return order, sz
    else:
        instance = [ds.get("InstanceNumber") for _, ds in slices]
        if None in instance:
            raise VolumeFormatError(f"{folder.name}: cannot order the DICOM slices: expected "
                                    "ImagePositionPatient/ImageOrientationPatient or InstanceNumber")
        order = np.argsort(np.array(instance, dtype=np.int64), kind="stable")
    ds = slices[0][1]
    sz = float(ds.get("SpacingBetweenSlices") or ds.get("SliceThickness") or 1.0)
    return order, sz
