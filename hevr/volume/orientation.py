"""One patient frame for every scan: hevr's loaders return volumes in RAS+.

The frame
---------
A loaded volume of shape (nz, ny, nx) has voxel (k, j, i) at world point
``origin + (i·sx, j·sy, k·sz)`` in millimetres of the **RAS+** patient frame:

* +x points to the patient's **R**\\ ight (x grows from the left side to the right side),
* +y points **A**\\ nterior (from the back to the front),
* +z points **S**\\ uperior (from the feet to the head).

RAS+ is NIfTI's and nibabel's canonical frame (``nib.as_closest_canonical``) and the
frame of most research tools (FreeSurfer, ITK-SNAP's RAS display, 3D Slicer's world).
DICOM and most NRRD files record LPS+ (x to the Left, y Posterior); their loaders negate the
first two world axes before calling :func:`to_patient_frame`. One frame is what makes the
camera's anatomical presets (``view="anterior"`` …) mean the same for every file.

How a file's geometry becomes the frame
---------------------------------------
A file gives a 4 × 4 affine ``A`` from voxel indices (i, j, k) (i the fastest array axis) to
RAS+ millimetres. Its columns ``A[:3, a]`` are the step vectors of the voxel axes; their
lengths are the spacings and their directions ``d_a`` the axis directions. Every voxel axis
is matched to the world axis it is closest to (largest ``|d_a[w]|``; each world axis once),
the array is transposed into that order and flipped where the direction is negative. Both
are numpy views: no voxel is copied, memory maps stay memory maps.

Oblique scans (gantry tilt, oblique MR planes) have directions that are not axis-aligned.
Reorienting them exactly would need resampling, which interpolates the voxels the owner
meant to encrypt and changes their values; hevr refuses instead (``oblique="refuse"``,
the default) when an axis is more than :data:`OBLIQUE_TOLERANCE_DEG` from its world axis,
and names the angle. ``oblique="snap"`` takes the nearest axes anyway (the image is then
rotated by at most that angle); the log says by how much.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..errors import ParameterError, VolumeFormatError

__all__ = ["FRAME", "OBLIQUE_TOLERANCE_DEG", "LPS_TO_RAS", "to_patient_frame", "axis_codes"]

_log = logging.getLogger(__name__)

FRAME = "RAS"
OBLIQUE_TOLERANCE_DEG = 1.0  # larger deviations are refused unless oblique="snap"

#: Multiplies an LPS+ affine (DICOM, NRRD ``left-posterior-superior``) into RAS+.
LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])

_POS, _NEG = "RAS", "LPI"


def axis_codes(affine: Any) -> str:
    """The world direction each voxel axis (i, j, k) points to, nibabel-style.

    >>> axis_codes(np.diag([1.0, 1.0, 1.0, 1.0]))
    'RAS'
    >>> axis_codes(np.diag([-2.0, 1.0, 1.0, 1.0]))
    'LAS'
    """
    m = np.asarray(affine, np.float64)[:3, :3]
    out = []
    for a in range(3):
        w = int(np.argmax(np.abs(m[:, a])))
        out.append(_POS[w] if m[w, a] > 0 else _NEG[w])
    return "".join(out)


def _match_axes(directions: np.ndarray) -> list[int]:
    """For each world axis w, the voxel axis closest to it (a permutation), greedily by |cos|."""
    cos = np.abs(directions)  # cos[w, a]
    world_of = [-1, -1, -1]
    taken_w, taken_a = set(), set()
    for flat in np.argsort(-cos, axis=None):
        w, a = divmod(int(flat), 3)
        if w in taken_w or a in taken_a:
            continue
        world_of[w] = a
        taken_w.add(w)
        taken_a.add(a)
    return world_of


def to_patient_frame(
    vol: np.ndarray, affine: Any, *, name: str, oblique: str = "refuse"
) -> tuple[np.ndarray, tuple[float, float, float], tuple[float, float, float]]:
    """Reorient ``vol`` (nz, ny, nx) with voxel→RAS+ ``affine`` into the RAS+ frame.

    Parameters
    ----------
    vol : numpy.ndarray
        Shape (nz, ny, nx) as stored (x = the fastest file axis = voxel index i).
    affine : array_like, shape (4, 4)
        Voxel (i, j, k, 1) → RAS+ millimetres.
    name : str
        The file, for messages.
    oblique : {"refuse", "snap"}
        What to do when an axis is more than :data:`OBLIQUE_TOLERANCE_DEG` off a world axis.

    Returns
    -------
    volume : numpy.ndarray
        A view of ``vol`` in RAS+ order (transposed/flipped, never copied).
    spacing : (sx, sy, sz)
        Voxel sizes along +x, +y, +z.
    origin : (x0, y0, z0)
        RAS+ position of the returned volume's voxel (0, 0, 0).

    Examples
    --------
    >>> v = np.arange(24).reshape(2, 3, 4)          # nz=2, ny=3, nx=4
    >>> lps = np.diag([0.5, 1.0, 2.0, 1.0])          # an LPS+ file: i runs to the left, j to the back
    >>> out, sp, org = to_patient_frame(v, LPS_TO_RAS @ lps, name="v")
    >>> sp, org
    ((0.5, 1.0, 2.0), (-1.5, -2.0, 0.0))
    >>> bool((out == v[:, ::-1, ::-1]).all())
    True
    """
    if oblique not in ("refuse", "snap"):
        raise ParameterError(f"oblique: expected 'refuse' or 'snap', got {oblique!r}")
    a = np.asarray(affine, dtype=np.float64)
    if a.shape != (4, 4) or not np.isfinite(a).all():
        raise VolumeFormatError(f"{name}: expected a finite 4x4 voxel-to-patient affine, got {a.tolist()!r}")
    steps = a[:3, :3]
    with np.errstate(over="ignore"):
        lengths = np.linalg.norm(steps, axis=0)
    if not np.isfinite(lengths).all():  # finite entries whose squares overflow (1e300 mm voxels)
        raise VolumeFormatError(
            f"{name}: expected voxel sizes within floating-point range, got step vectors {steps.tolist()!r}"
        )
    if not (lengths > 0).all() or abs(np.linalg.det(steps)) < 1e-12 * float(np.prod(lengths)):
        raise VolumeFormatError(
            f"{name}: the voxel axes in the file's geometry are degenerate "
            f"(directions {np.round(steps, 6).tolist()}); expected 3 independent axes"
        )
    directions = steps / lengths
    world_of = _match_axes(directions)  # world axis w <- voxel axis world_of[w]
    worst = max(math.degrees(math.acos(min(1.0, abs(directions[w, world_of[w]])))) for w in range(3))
    if worst > OBLIQUE_TOLERANCE_DEG:
        if oblique == "refuse":
            raise VolumeFormatError(
                f"{name}: the scan is oblique: a voxel axis is {worst:.2f} degrees off the patient axes "
                f"(at most {OBLIQUE_TOLERANCE_DEG} accepted); hevr does not resample encrypted data, so "
                "reslice it to axial/coronal/sagittal first, or pass oblique='snap' (CLI --oblique snap) "
                "to take the nearest axes"
            )
        _log.warning("%s: oblique scan, snapped to the nearest patient axes (up to %.2f degrees off)", name, worst)
    ijk = vol.transpose(2, 1, 0)  # axes (i, j, k)
    xyz = ijk.transpose(world_of)  # axis w is voxel axis world_of[w]
    corner = np.zeros(3)
    flips = []
    for w in range(3):
        ax = world_of[w]
        if directions[w, ax] < 0:
            flips.append(w)
            corner[ax] = vol.shape[2 - ax] - 1
    if flips:
        index: list[Any] = [slice(None)] * 3
        for w in flips:
            index[w] = slice(None, None, -1)
        xyz = xyz[tuple(index)]
    origin = a[:3, :3] @ corner + a[:3, 3]
    spacing = tuple(float(lengths[world_of[w]]) for w in range(3))
    out = xyz.transpose(2, 1, 0)
    _log.debug("%s: stored %s, reoriented to RAS (flipped world axes %s)", name, axis_codes(a), flips)
    return out, spacing, tuple(float(v) for v in origin)  # type: ignore[return-value]
