"""DICOM frames: each image frame of a series with its own geometry and rescale factors.

Frames
------
Every image frame of a series becomes a :class:`Frame` with its own position, orientation,
pixel spacing and rescale factors, whatever file layout it came in:

* single-frame files (classic CT/MR): the top-level ``ImagePositionPatient`` (IPP),
  ``ImageOrientationPatient`` (IOP), ``PixelSpacing``, ``RescaleSlope/Intercept``;
* enhanced multi-frame files (Enhanced CT/MR/PET): per frame, the ``PlanePositionSequence``,
  ``PlaneOrientationSequence``, ``PixelMeasuresSequence`` and
  ``PixelValueTransformationSequence`` items of the ``PerFrameFunctionalGroupsSequence``,
  else of the ``SharedFunctionalGroupsSequence``;
* RT dose files scale by ``DoseGridScaling`` (to Gy) where others have ``RescaleSlope``;
* legacy multi-frame files (NM, RT dose, …): frame k lies at ``IPP + o_k · n`` with the
  ``GridFrameOffsetVector`` offsets o_k, else ``o_k = k · SpacingBetweenSlices`` (or
  ``SliceThickness``), n the slice normal; NM files keep IPP/IOP in their
  ``DetectorInformationSequence``.

A ``NumberOfFrames`` the file is too small to hold, and functional groups that are not sequences
of items, are refused before any frame is built. How the frames stack (their order, gaps, tilt
and the voxel→LPS affine) is :mod:`hevr.volume.dicom_stack`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import VolumeFormatError
from .dicom_mosaic import Mosaic, mosaic_of, tile_position
from .dicom_series import Image

__all__ = ["Frame", "frames_of"]

_log = logging.getLogger(__name__)

# Implicit VR LE, explicit VR LE, explicit VR BE: pixel data stored as is, one frame after the other.
_NATIVE = ("1.2.840.10008.1.2", "1.2.840.10008.1.2.1", "1.2.840.10008.1.2.2")


@dataclass(frozen=True)
class Frame:
    """One image frame: where it lies and how its stored values become real values."""

    image: Image
    index: int  # frame number within its file (0 for single-frame files)
    position: tuple[float, ...] | None  # IPP, LPS mm
    orientation: tuple[float, ...] | None  # IOP (row direction, column direction)
    pixel_spacing: tuple[float, ...] | None  # (between rows, between columns)
    thickness: float | None  # SpacingBetweenSlices, else SliceThickness
    slope: float
    intercept: float
    instance: int | None
    mosaic: Mosaic | None = None  # a Siemens MOSAIC: ``index`` is the slice's tile

    @property
    def label(self) -> str:
        """``IM0001.dcm``, ``enhanced.dcm frame 7`` or ``epi.dcm slice 3`` (1-based), for messages."""
        if self.mosaic is not None:
            return f"{self.image.path.name} slice {self.index + 1}"
        return self.image.path.name + (f" frame {self.index + 1}" if self.image.frames > 1 else "")

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of this frame's pixels: a mosaic's tile, else the image's."""
        if self.mosaic is not None:
            return self.mosaic.rows, self.mosaic.columns
        return int(self.image.header.get("Rows") or 0), int(self.image.header.get("Columns") or 0)


def _floats(label: str, key: str, value: Any, n: int) -> tuple[float, ...] | None:
    if value is None or value == "":
        return None
    try:
        out = tuple(float(v) for v in (value if n > 1 else [value]))
    except (TypeError, ValueError):
        out = ()
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise VolumeFormatError(f"{label}: {key}: expected {n} finite number(s), got {str(value)[:60]!r}")
    return out


def _items(label: str, key: str, value: Any) -> list[Any]:
    """The items of a sequence element (``[]`` when absent); anything else is refused."""
    if value is None or value == "":
        return []
    try:
        items = None if isinstance(value, (str, bytes)) else list(value)
    except TypeError:
        items = None
    if items is None or not all(hasattr(v, "get") and hasattr(v, "__contains__") for v in items):
        raise VolumeFormatError(f"{label}: {key}: expected a sequence of items, got {str(value)[:40]!r}")
    return items


def _item(label: str, groups: list[Any], keyword: str) -> Any | None:
    """The first item of ``keyword`` in the first functional group that has it."""
    for g in groups:
        if g is not None and keyword in g:
            items = _items(label, keyword, g[keyword].value)
            if items:
                return items[0]
    return None


def _count(ds: Any, key: str) -> int:
    """A positive integer attribute, or 1 when absent or invalid (the lenient bound)."""
    try:
        value = int(ds.get(key))
    except (TypeError, ValueError):
        return 1
    return max(value, 1)


def _check_frame_count(image: Image) -> int:
    """``NumberOfFrames``, refused when the file is too small to hold that many frames.

    Every frame costs a :class:`Frame` before any pixel is read: a forged count of 10**7 in
    a tiny file took minutes. Native (uncompressed) pixel data needs rows × columns ×
    samples × BitsAllocated / 8 bytes per frame, encapsulated data an 8-byte item per frame.
    """
    ds, n = image.header, image.frames
    if n == 1:
        return n
    meta = getattr(ds, "file_meta", None) or {}
    syntax = str(meta.get("TransferSyntaxUID", "1.2.840.10008.1.2"))
    if syntax in _NATIVE:
        per = (
            _count(ds, "Rows")
            * _count(ds, "Columns")
            * _count(ds, "SamplesPerPixel")
            * min(_count(ds, "BitsAllocated"), 64)
            / 8
        )
    else:
        per = 8
    size = image.path.stat().st_size
    if n * per > size:
        raise VolumeFormatError(
            f"{image.path.name}: NumberOfFrames: {n} frames need at least {math.ceil(n * per)} "
            f"bytes of pixel data, the file holds {size} bytes"
        )
    return n


def _get(sources: list[Any], key: str) -> Any:
    for src in sources:
        if src is not None and src.get(key) not in (None, ""):
            return src.get(key)
    return None


def frames_of(image: Image) -> list[Frame]:
    """The frames of one file, each with its geometry and rescale factors."""
    ds, n, name = image.header, _check_frame_count(image), image.path.name
    shared_seq = _items(name, "SharedFunctionalGroupsSequence", ds.get("SharedFunctionalGroupsSequence"))
    shared = shared_seq[0] if shared_seq else None
    per = _items(name, "PerFrameFunctionalGroupsSequence", ds.get("PerFrameFunctionalGroupsSequence"))
    if per and len(per) != n:
        raise VolumeFormatError(
            f"{name}: PerFrameFunctionalGroupsSequence: expected {n} items (NumberOfFrames), got {len(per)}"
        )
    detector = _items(name, "DetectorInformationSequence", ds.get("DetectorInformationSequence"))
    top = [ds] + detector[:1]  # NM keeps IPP/IOP per detector
    legacy_offsets = None
    if n > 1 and not per:
        legacy_offsets = _floats(name, "GridFrameOffsetVector", ds.get("GridFrameOffsetVector"), n)
    out = []
    for k in range(n):
        groups = [per[k] if per else None, shared]
        label = name + (f" frame {k + 1}" if n > 1 else "")
        plane_pos = _item(label, groups, "PlanePositionSequence")
        plane_ori = _item(label, groups, "PlaneOrientationSequence")
        measures = _item(label, groups, "PixelMeasuresSequence")
        values = _item(label, groups, "PixelValueTransformationSequence")
        pos = _floats(label, "ImagePositionPatient", _get([plane_pos] + top, "ImagePositionPatient"), 3)
        iop = _floats(label, "ImageOrientationPatient", _get([plane_ori] + top, "ImageOrientationPatient"), 6)
        spacing = _floats(label, "PixelSpacing", _get([measures, ds], "PixelSpacing"), 2)
        thick = _floats(label, "SpacingBetweenSlices", _get([measures, ds], "SpacingBetweenSlices"), 1) or _floats(
            label, "SliceThickness", _get([measures, ds], "SliceThickness"), 1
        )
        if n > 1 and not per:
            pos = _legacy_position(label, pos, iop, k, legacy_offsets, thick)
        slope = (
            _floats(label, "RescaleSlope", _get([values, ds], "RescaleSlope"), 1)
            or _floats(label, "DoseGridScaling", ds.get("DoseGridScaling"), 1)
            or (1.0,)
        )  # RT dose: Gy
        inter = _floats(label, "RescaleIntercept", _get([values, ds], "RescaleIntercept"), 1) or (0.0,)
        try:
            instance = int(ds.get("InstanceNumber")) * n + k if ds.get("InstanceNumber") is not None else None
        except (TypeError, ValueError):
            instance = None
        out.append(Frame(image, k, pos, iop, spacing, thick[0] if thick else None, slope[0] or 1.0, inter[0], instance))
    mosaic = mosaic_of(ds, image.path) if n == 1 else None
    return _tiles(out[0], mosaic) if mosaic is not None else out


def _tiles(whole: Frame, mosaic: Mosaic) -> list[Frame]:
    """The slices of a Siemens MOSAIC image, each placed (:mod:`hevr.volume.dicom_mosaic`)."""
    where = None  # ImagePositionPatient, ImageOrientationPatient, PixelSpacing: the mosaic's corner and axes
    if whole.position is not None and whole.orientation is not None and whole.pixel_spacing is not None:
        where = (whole.position, whole.orientation, whole.pixel_spacing)
    placed = where is not None
    gap = abs(whole.thickness or 1.0)
    if placed and not whole.thickness:
        _log.warning(
            "%s: a MOSAIC without SpacingBetweenSlices or SliceThickness; assuming its slices 1 mm apart",
            whole.image.path.name,
        )
    out = []
    for k in range(mosaic.slices):
        pos = tile_position(mosaic, *where, gap, k) if where is not None else None
        instance = None if whole.instance is None else whole.instance * mosaic.slices + k
        out.append(dataclasses.replace(whole, index=k, position=pos, instance=instance, mosaic=mosaic))
    return out


def _legacy_position(label: str, ipp: Any, iop: Any, k: int, offsets: Any, thick: Any) -> tuple[float, ...] | None:
    """Frame k of a legacy multi-frame file: ``IPP + o_k · n`` (see the module docstring)."""
    if ipp is None or iop is None:
        return None
    normal = np.cross(iop[:3], iop[3:])
    if offsets is not None:
        step = offsets[k] - offsets[0]
    elif thick is not None:
        step = k * thick[0]
    else:
        if k == 1:
            _log.warning(
                "%s: multi-frame file without GridFrameOffsetVector or slice spacing; assuming frames 1 mm apart", label
            )
        step = float(k)
    return tuple(float(v) for v in np.asarray(ipp) + step * normal)
