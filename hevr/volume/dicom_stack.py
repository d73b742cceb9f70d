"""How DICOM frames (:mod:`hevr.volume.dicom_frames`) stack into one volume: their order
along the slice normal, the gaps between them, gantry tilt, and the voxel→LPS affine.

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
placed frames would otherwise silently lose their orientation).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import VolumeFormatError
from .dicom_frames import Frame
from .orientation import OBLIQUE_TOLERANCE_DEG

__all__ = ["GAP_TOLERANCE", "Stack", "plan_stack"]

_log = logging.getLogger(__name__)

GAP_TOLERANCE = 0.01  # relative: the slice gaps may spread by 1 % of their median


@dataclass(frozen=True)
class Stack:
    """How the frames stack: their order and the voxel→LPS affine (None: no geometry)."""

    order: list[int]
    affine: np.ndarray | None
    spacing: tuple[float, float, float]
    uneven: bool = False


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
