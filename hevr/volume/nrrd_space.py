"""NRRD geometry: ``space``, ``space directions``, ``space origin`` and ``kinds`` → a :class:`Scan`.

The frame
---------
An NRRD file with an anatomical ``space`` records where its voxels lie in the patient:
``space directions`` holds one step vector per spatial axis (fastest first), ``space origin``
the position of the first voxel, both in the named space. The anatomical spaces are
turned into RAS+ by negating the world axes that point the other way::

    right-anterior-superior (RAS)   ( 1,  1, 1)
    left-anterior-superior  (LAS)   (-1,  1, 1)
    left-posterior-superior (LPS)   (-1, -1, 1)   (what DICOM-derived files, Slicer and ITK write)

(and their ``-time`` variants, whose vectors have a 4th, time, component that is dropped).
The voxel → RAS+ affine then goes to :func:`hevr.volume.orientation.to_patient_frame`,
which transposes/flips the array as views. ``scanner-xyz``, ``3D-right-handed``,
``3D-left-handed`` and files without ``space`` (or without ``space directions``) carry no
patient orientation: the axes stay as stored (``frame=None``), the spacing is the length
of each direction vector (or ``spacings``; NaN there means unknown → 1).

4-D files
---------
hevr encrypts one scalar per voxel. In a 4-D file exactly one axis must be non-spatial:
the axis whose direction is ``none``, else the one whose kind is not ``domain``/``space``,
else the slowest (4th) axis. Its entries are *time points/volumes* when its kind is
``time``, ``domain``, ``space``, ``none`` or unknown, and *components* for ``vector``,
``RGB-color``, ``covariant-vector``, ``list``, … . Either way ``volume=i`` picks one
(a view: the other entries are not read when the data is memory-mapped); without it a
file with more than one entry is refused.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import VolumeFormatError
from ._select import reject_index, select_index
from .nrrd import read_nrrd
from .orientation import FRAME, to_patient_frame
from .scan import Scan

__all__ = ["read_nrrd_scan", "SPACE_SIGNS"]

_log = logging.getLogger(__name__)

#: RAS+ signs of each anatomical NRRD space (long and short names, with and without -time).
SPACE_SIGNS: dict[str, tuple[float, float, float]] = {}
for _long, _short, _signs in (
    ("right-anterior-superior", "ras", (1.0, 1.0, 1.0)),
    ("left-anterior-superior", "las", (-1.0, 1.0, 1.0)),
    ("left-posterior-superior", "lps", (-1.0, -1.0, 1.0)),
):
    SPACE_SIGNS.update(dict.fromkeys((_long, _short, _long + "-time", _short + "t"), _signs))
_NO_PATIENT = {
    "scanner-xyz",
    "3d-right-handed",
    "3d-left-handed",
    "scanner-xyz-time",
    "3d-right-handed-time",
    "3d-left-handed-time",
}
_SPATIAL_KINDS = {"domain", "space"}
_SCALAR_KINDS = {"domain", "space", "time", "none", "???"}  # a 3-D file with another kind is not scalar
_VOLUME_KINDS = {"time", "domain", "space", "none", "???", ""}
_TOKEN = re.compile(r"\(([^()]*)\)|(none)", re.IGNORECASE)


def _fail(path: Path, problem: str) -> VolumeFormatError:
    return VolumeFormatError(f"{path.name}: {problem}")


def _vector(path: Path, field: str, text: str) -> list[float]:
    try:
        return [float(c) for c in text.split(",")]
    except ValueError:
        raise _fail(path, f"NRRD field '{field}' has a non-numeric vector: ({text})") from None


def _directions(path: Path, fields: dict[str, str], dim: int) -> list[list[float] | None] | None:
    """One step vector per axis (None for ``none``), or None when the file has none."""
    value = fields.get("space directions")
    if value is None:
        return None
    out = [None if none else _vector(path, "space directions", vec) for vec, none in _TOKEN.findall(value)]
    spatial = [v for v in out if v is not None]
    if len(out) != dim or len(spatial) != 3 or len({len(v) for v in spatial}) != 1 or len(spatial[0]) not in (3, 4):
        raise _fail(
            path,
            f"NRRD field 'space directions' must hold three vectors like '(1,0,0) (0,1,0) (0,0,1)' "
            f"for the three spatial axes ('none' for a {dim}-D file's other axis), got {value!r}",
        )
    return out


def _extra_axis(path: Path, dim: int, kinds: list[str], dirs: list | None) -> int | None:
    """The non-spatial axis of a 4-D file (file order, fastest first); None for 3-D."""
    if dim == 3:
        if any(k not in _SCALAR_KINDS for k in kinds):
            raise _fail(
                path, f"expected a scalar 3-D volume, got axis kinds {' '.join(kinds)!r} (a vector or colour axis)"
            )
        return None
    if dirs is not None:
        return next(a for a, d in enumerate(dirs) if d is None)
    other = [a for a, k in enumerate(kinds) if k not in _SPATIAL_KINDS]
    if kinds and len(other) != 1:
        raise _fail(path, f"a 4-D NRRD file needs exactly one non-spatial axis, got kinds {' '.join(kinds)!r}")
    return other[0] if other else 3


def _plan(path: Path, fields: dict[str, str], shape: tuple[int, ...], volume: int | None) -> dict[str, Any]:
    """Everything the header decides, checked before the data is read."""
    dim = len(shape)
    kinds = fields.get("kinds", "").lower().split()
    if kinds and len(kinds) != dim:
        raise _fail(path, f"NRRD field 'kinds' must name {dim} axes, got {fields['kinds']!r}")
    dirs = _directions(path, fields, dim)
    extra = _extra_axis(path, dim, kinds, dirs)
    details: dict[str, Any] = {"encoding": fields["encoding"].lower(), "kinds": kinds or None}
    take: list[Any] = [slice(None)] * dim
    if extra is None:
        reject_index(volume, path)
    else:
        kind = kinds[extra] if kinds else ""
        count = shape[dim - 1 - extra]
        if kind in _VOLUME_KINDS:
            what, axis = "volumes", f"its axis {extra} (kind {kind or 'unknown'})"
        else:
            what, axis = (
                f"{kind} components",
                (f"its axis {extra}; hevr encrypts one scalar per voxel, so pick a component"),
            )
        take[dim - 1 - extra] = select_index(volume, count, path, what, axis)
        details.update(volume=take[dim - 1 - extra], volumes=count)
        if dirs is not None:
            dirs = dirs[:extra] + dirs[extra + 1 :]
    steps = None if dirs is None else np.array([d[:3] for d in dirs], np.float64).T  # type: ignore[index]
    space = " ".join(fields.get("space", "").lower().split())
    if space and space not in SPACE_SIGNS and space not in _NO_PATIENT:
        raise _fail(
            path,
            f"NRRD field 'space': expected one of right-anterior-superior, left-anterior-superior, "
            f"left-posterior-superior (RAS/LAS/LPS), scanner-xyz, 3D-right-handed or "
            f"3D-left-handed, got {fields['space']!r}",
        )
    details["space"] = space or None
    origin = np.zeros(3)
    origin_text = fields.get("space origin", "").strip()
    if origin_text:
        values = _vector(path, "space origin", origin_text.strip("()"))
        if len(values) not in (3, 4) or not all(math.isfinite(v) for v in values):
            raise _fail(path, f"NRRD field 'space origin' must be a finite 3-vector like (0,0,0), got {origin_text!r}")
        origin = np.array(values[:3])
    return {
        "take": tuple(take),
        "steps": steps,
        "spacing": _spacing(path, fields, steps, extra),
        "space": space,
        "origin": origin,
        "details": details,
    }


def read_nrrd_scan(path: Path, *, volume: int | None = None, oblique: str = "refuse") -> Scan:
    """Read an NRRD file into a :class:`Scan` (RAS+ when its ``space`` is anatomical)."""
    arr, _, plan = read_nrrd(path, lambda fields, shape: _plan(path, fields, shape, volume))
    arr = arr[plan["take"]]  # one volume of a 4-D file: a view
    space, steps, origin, details = plan["space"], plan["steps"], plan["origin"], plan["details"]
    if space not in SPACE_SIGNS or steps is None:
        if space in SPACE_SIGNS:
            _log.warning("%s: space %s but no 'space directions'; axes kept as stored", path.name, space)
        ox, oy, oz = (float(v) for v in origin)  # a 3-vector (_plan)
        return Scan(arr, plan["spacing"], (ox, oy, oz), None, None, str(path), details)
    signs = np.array(SPACE_SIGNS[space])
    affine = np.eye(4)
    affine[:3, :3] = signs[:, None] * steps
    affine[:3, 3] = signs * origin
    vol, spacing, org = to_patient_frame(arr, affine, name=path.name, oblique=oblique)
    return Scan(vol, spacing, org, FRAME, None, str(path), details)


def _spacing(
    path: Path, fields: dict[str, str], steps: np.ndarray | None, extra: int | None
) -> tuple[float, float, float]:
    """Voxel sizes (sx, sy, sz) of the stored axes: direction lengths, else ``spacings``, else 1."""
    if steps is not None:
        out = [float(v) for v in np.linalg.norm(steps, axis=0)]
        if fields.get("space", "").lower() not in SPACE_SIGNS and not all(
            abs(steps[i, i]) >= out[i] * (1 - 1e-9) for i in range(3)
        ):
            _log.info(
                "%s: non-axis-aligned space directions %s without a patient space; only their lengths %s are used",
                path.name,
                fields["space directions"],
                out,
            )
    elif "spacings" in fields:
        try:
            # NaN means "unknown" in NRRD: fall back to 1 like teem's tools do.
            out = [1.0 if math.isnan(float(v)) else float(v) for v in fields["spacings"].split()]
        except ValueError:
            out = []
        if len(out) != 3 + (extra is not None):
            raise _fail(
                path, f"NRRD field 'spacings' must hold {3 + (extra is not None)} numbers, got {fields['spacings']!r}"
            )
        if extra is not None:
            del out[extra]
    else:
        out = [1.0, 1.0, 1.0]
    if not all(math.isfinite(v) and v > 0 for v in out):
        raise _fail(path, f"NRRD spacing must be three positive finite numbers, got {tuple(out)}")
    return out[0], out[1], out[2]
