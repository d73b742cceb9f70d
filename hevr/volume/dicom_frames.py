"""DICOM frames and how they stack: per-frame geometry and the voxel→LPS affine.

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

The stack
---------
With unit row direction r = IOP[:3] (along the columns index i) and column direction
c = IOP[3:] (along the rows index j), the slice normal is n = r × c. Frames are sorted by
``d_k = IPP_k · n``; neighbouring frames must differ in d (else: a duplicate, an error), and
the largest and smallest gap by at most :data:`GAP_TOLERANCE` of the median gap g (else:
uneven spacing, refused unless ``allow_uneven``, which stacks them g apart). The slice step s is the median over
neighbours of ``(IPP_k+1 − IPP_k) · g / (d_k+1 − d_k)`` (so s · n = g); a slice off the line
``IPP_k ≈ IPP_0 + (d_k − d_0) / g · s`` by more than half a pixel is refused; with ``PixelSpacing = (Δj, Δi)``
the voxel (i, j, k) → LPS affine has the columns ``Δi·r``, ``Δj·c``, ``s`` and the
translation IPP_first. A step off the normal by more than
:data:`~hevr.volume.orientation.OBLIQUE_TOLERANCE_DEG` is a gantry tilt (sheared slices):
refused, or with ``oblique="snap"`` replaced by ``g·n`` (the slices stacked unsheared, g
apart, which keeps the plane distance exact).

Without IPP/IOP on any frame, the frames are ordered by ``InstanceNumber`` (frame order within a file)
and spaced by ``SpacingBetweenSlices``/``SliceThickness`` (else 1), with no patient frame; a
series where some frames have IPP/IOP and others not is refused (a damaged file, whose
placed frames would otherwise silently lose their orientation). A ``NumberOfFrames`` the
file is too small to hold, and functional groups that are not sequences of items, are refused
before any frame is built.
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
from .orientation import OBLIQUE_TOLERANCE_DEG

__all__ = ["GAP_TOLERANCE", "Frame", "Stack", "frames_of", "plan_stack"]

_log = logging.getLogger(__name__)

GAP_TOLERANCE = 0.01  # relative: the slice gaps may spread by 1 % of their median
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


@dataclass(frozen=True)
class Stack:
    """How the frames stack: their order and the voxel→LPS affine (None: no geometry)."""

    order: list[int]
    affine: np.ndarray | None
    spacing: tuple[float, float, float]
    uneven: bool = False


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


def _check_same(frames: list[Frame], name: str, attr: str, what: str, tol: float) -> None:
    first = getattr(frames[0], attr)
    for f in frames[1:]:
        v = getattr(f, attr)
        if (v is None) != (first is None) or (v is not None and np.max(np.abs(np.subtract(v, first))) > tol):
            raise VolumeFormatError(
                f"{name}: {what}: expected one value for the whole series, got {first} in {frames[0].label} "
                f"and {v} in {f.label}; a series with several stacks (a localizer?) cannot be one volume, "
                "choose another series"
            )


def plan_stack(frames: list[Frame], name: str, *, allow_uneven: bool, oblique: str) -> Stack:
    """Order the frames and build the voxel→LPS affine (see the module docstring)."""
    ps = frames[0].pixel_spacing
    _check_same(frames, name, "pixel_spacing", "PixelSpacing", 1e-4 * max(ps or (1.0,)))
    if ps is None:
        _log.warning("%s: no PixelSpacing; assuming 1 x 1 mm pixels", name)
        ps = (1.0, 1.0)
    placed = [f.position is not None and f.orientation is not None for f in frames]
    if not all(placed):
        if any(placed):  # some frames placed, others not: a damaged file, not "no geometry"
            lost = frames[placed.index(False)]
            raise VolumeFormatError(
                f"{name}: {lost.label} lacks ImagePositionPatient/ImageOrientationPatient "
                f"that {frames[placed.index(True)].label} has; expected patient geometry for "
                "every slice of the series, or for none"
            )
        return _by_instance(frames, name, ps)
    _check_same(frames, name, "orientation", "ImageOrientationPatient", 1e-3)
    iop = np.asarray(frames[0].orientation)
    row, col = iop[:3], iop[3:]
    if abs(np.linalg.norm(row) - 1) > 1e-2 or abs(np.linalg.norm(col) - 1) > 1e-2 or abs(row @ col) > 1e-2:
        raise VolumeFormatError(
            f"{name}: ImageOrientationPatient: expected two orthogonal unit vectors, got {iop.tolist()}"
        )
    row, col = row / np.linalg.norm(row), col / np.linalg.norm(col)
    normal = np.cross(row, col)
    pos = np.array([f.position for f in frames], np.float64)
    d = pos @ normal
    order = np.argsort(d, kind="stable")
    uneven = False
    if len(frames) == 1:
        g = abs(frames[0].thickness or 1.0)
        step = g * normal
    else:
        gaps = np.diff(d[order])
        if gaps.min() < 1e-4:
            i = int(np.argmin(gaps))
            raise VolumeFormatError(
                f"{name}: slices {frames[order[i]].label} and {frames[order[i + 1]].label} lie at the same "
                f"position {d[order[i]]:.4g} mm; expected one slice per position (several echoes, phases or "
                f"b-values in one series cannot be one volume){_one_file_hint(frames)}"
            )
        g = float(np.median(gaps))
        off = np.flatnonzero(np.abs(gaps - g) > GAP_TOLERANCE * g / 2)
        if gaps.max() - gaps.min() > GAP_TOLERANCE * g:
            uneven = True
            pairs = ", ".join(
                f"{frames[order[i]].label} to {frames[order[i + 1]].label}: {gaps[i]:.4g} mm" for i in off[:3]
            ) + (f" and {len(off) - 3} more" if len(off) > 3 else "")
            if not allow_uneven:
                raise VolumeFormatError(
                    f"{name}: uneven slice spacing: expected the slices {g:.4g} mm apart (the median gap), "
                    f"got {pairs} (a missing slice?); pass allow_uneven=True to stack them {g:.4g} mm apart "
                    "anyway (distorts distances)"
                )
            _log.warning("%s: uneven slice spacing (%s); stacking them %.4g mm apart", name, pairs, g)
        step = np.median(np.diff(pos[order], axis=0) / gaps[:, None], axis=0) * g
        _check_line(frames, pos, d, order, step, g, name, ps)
        tilt = math.degrees(math.acos(min(1.0, float(step @ normal) / float(np.linalg.norm(step)))))
        if tilt > OBLIQUE_TOLERANCE_DEG:
            if oblique == "refuse":
                raise VolumeFormatError(
                    f"{name}: the slices are sheared by a gantry tilt of {tilt:.2f} degrees (at most "
                    f"{OBLIQUE_TOLERANCE_DEG} accepted); hevr does not resample encrypted data, so pass "
                    "oblique='snap' (CLI --oblique snap) to stack them unsheared"
                )
            _log.warning("%s: gantry tilt of %.2f degrees; stacking the slices unsheared, %.4g mm apart", name, tilt, g)
            step = g * normal
    spacing = (float(ps[1]), float(ps[0]), float(np.linalg.norm(step)))
    if not (ps[0] > 0 and ps[1] > 0):  # passed on as recorded: the caller rejects it or overrides it
        _log.warning("%s: PixelSpacing %s is not positive; axes kept as stored, no patient frame", name, ps)
        return Stack([int(i) for i in order], None, spacing, uneven)
    affine = np.eye(4)
    affine[:3, 0], affine[:3, 1], affine[:3, 2] = row * ps[1], col * ps[0], step
    affine[:3, 3] = pos[order[0]]
    return Stack([int(i) for i in order], affine, spacing, uneven)


def _one_file_hint(frames: list[Frame]) -> str:
    """Where every file holds a whole volume (multi-frame, mosaic): say that one file reads."""
    if all(f.mosaic is not None or f.image.frames > 1 for f in frames):
        return "; each file holds a whole volume: name one file to read that volume"
    return ""


def _check_line(
    frames: list[Frame],
    pos: np.ndarray,
    d: np.ndarray,
    order: np.ndarray,
    step: np.ndarray,
    g: float,
    name: str,
    ps: tuple[float, ...],
) -> None:
    """Refuse slices whose in-plane offsets do not follow one line (stacks of different fields)."""
    residual = pos[order] - np.outer((d[order] - d[order[0]]) / g, step)
    err = np.linalg.norm(residual - np.median(residual, axis=0), axis=1)
    k = int(np.argmax(err))
    if err[k] > 0.5 * max(min(abs(v) for v in ps), 1e-3):
        raise VolumeFormatError(
            f"{name}: slice {frames[order[k]].label} is shifted {err[k]:.3g} mm within its "
            "plane against the others; expected one stack of aligned slices"
        )


def _by_instance(frames: list[Frame], name: str, ps: tuple[float, ...]) -> Stack:
    """No patient geometry: order by InstanceNumber (frames in file order), axes as stored."""
    if len(frames) > 1 and any(f.instance is None for f in frames) and len({f.image.path for f in frames}) > 1:
        raise VolumeFormatError(
            f"{name}: cannot order the DICOM slices: expected "
            "ImagePositionPatient/ImageOrientationPatient or InstanceNumber"
        )
    order = sorted(range(len(frames)), key=lambda i: (frames[i].instance or 0, i))
    sz = abs(frames[0].thickness or 1.0)
    _log.warning(
        "%s: no ImagePositionPatient/ImageOrientationPatient; slices in InstanceNumber order, "
        "%.4g mm apart, axes as stored (no patient frame)",
        name,
        sz,
    )
    return Stack(order, None, (float(ps[1]), float(ps[0]), float(sz)))
