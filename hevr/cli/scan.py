"""The command line's side of real scans: reading an INPUT (``phantom:N``, ``sample:mri``, a file
or folder), modality value ranges, ``--tf`` presets turned into nodes, and what ``hevr info``
says about a scan or a DICOM folder. The options themselves (``--modality``, ``--view``, the scan
options of ``hevr encrypt``) are in :mod:`hevr.cli.render_options` and :mod:`hevr.cli.options`.

How ``hevr encrypt`` picks the value range (the density normalisation, public in the store)
-------------------------------------------------------------------------------------------
1. ``--value-range LO,HI`` when given;
2. else the modality's fixed range (:mod:`hevr.volume.modality`): ``--modality CT|MR|US``, or with
   ``--modality auto`` (the default) the modality the file records (DICOM ``Modality``);
   NIfTI, NRRD and the headerless formats record none;
3. else the library default: the dtype's range for integers, the data range for floats.

Never a range computed from the voxels unless they are floats without a modality (then the
data range is today's default, as in :func:`hevr.encrypt_volume`). The owner's data min/max
only feed :func:`hevr.volume.modality.range_hint`, a warning on stderr when the data occupy a
tiny band of the chosen range (a flat render) or run above it.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import check_regular
from ..errors import MissingFileError, ParameterError, VolumeFormatError
from ..paper import PAPER_SIZE
from ..volume.density import default_value_range, minmax
from ..volume.dicom import list_series
from ..volume.loaders import read_scan
from ..volume.modality import MODALITY_RANGES, range_hint, tf_preset
from ..volume.phantom import phantom
from ..volume.samples import SAMPLES, sample_scan
from ..volume.scan import Scan
from .options import MAX_PHANTOM, phantom_size_type
from .util import UsageError, warn_line, xyz

__all__ = ["encrypt_input", "load_input", "load_scan", "resolve_tf", "scan_rows"]

log = logging.getLogger(__name__)


# -- inputs -------------------------------------------------------------------------------------
def load_input(spec: str, spacing: Any = None) -> tuple[np.ndarray, tuple[float, float, float], str]:
    """:func:`load_scan` reduced to (volume, spacing, description)."""
    scan, what = load_scan(spec, spacing)
    return scan.volume, scan.spacing, what


def load_scan(spec: str, spacing: Any = None, **read: Any) -> tuple[Scan, str]:
    """``phantom:N`` (or ``phantom``), ``sample:mri`` (:func:`hevr.sample_scan`) or any
    file/folder :func:`hevr.read_scan` reads.

    ``read``: read_scan's ``series``, ``volume``, ``allow_uneven``, ``oblique``. Returns the
    scan and a description; its frame, modality and origin are logged at INFO. Errors name
    the volume ``input``: each command says which of its arguments that is (``INPUT``,
    ``--input``, ``PATH``).
    """

    if spec == "phantom" or spec.startswith("phantom:"):
        size_text = spec.partition(":")[2] or str(PAPER_SIZE)
        try:
            size = phantom_size_type(size_text)
        except argparse.ArgumentTypeError:
            raise UsageError(
                f"input: expected phantom:N with an integer N in [4, {MAX_PHANTOM}] "
                f"(e.g. phantom:{PAPER_SIZE}), got {spec!r}"
            ) from None
        given = [k for k, v in read.items() if v not in (None, False, "refuse")]
        if given:
            raise UsageError(f"{', '.join(given)}: expected a scan file or folder as INPUT, got {spec!r}")
        vol = phantom(size)
        sp = tuple(float(v) for v in spacing) if spacing else (1.0, 1.0, 1.0)
        return Scan(vol, sp, source=spec), f"phantom, {xyz(vol.shape)} voxels (uint8)"  # type: ignore[arg-type]
    if spec.startswith("sample:") and not Path(spec).exists():  # a real scan an installed package ships
        name = spec.partition(":")[2]
        if name not in SAMPLES:
            raise UsageError(f"input: expected sample:NAME with NAME one of {', '.join(SAMPLES)}, got {spec!r}")
        path = sample_scan(name)
    else:
        path = Path(spec).expanduser()
    if not path.exists():
        raise MissingFileError("input", "a volume file, a DICOM folder, phantom:N or sample:mri", spec)
    if not path.is_dir():
        check_regular(path, "input", "a volume file")  # a FIFO or a device: named as the input, never read
    try:
        scan = read_scan(path, spacing=spacing, **read)
    except MissingFileError as exc:  # a file the input refers to (an .nhdr's detached data file)
        raise VolumeFormatError(f"input: {spec} refers to {exc.filename}, which does not exist") from None
    log.info(
        "%s: %s, modality %s, origin %s mm",
        spec,
        "RAS+ patient frame" if scan.frame else "axes as stored (no patient frame recorded)",
        scan.modality or "not recorded",
        scan.origin,
    )
    vol = scan.volume
    return scan, f"{path.name}, {xyz(vol.shape)} voxels ({vol.dtype})"


def resolve_tf(tf: Any, value_range: Any) -> Any:
    """Nodes from ``--tf`` (:func:`hevr.cli.render_options.tf_type`): a preset name becomes nodes for
    the store's ``value_range``; nodes and ``None`` pass through."""
    if not isinstance(tf, str):
        return tf
    try:
        return tf_preset(tf, value_range)
    except ParameterError as exc:
        raise ParameterError(f"--tf {tf}: {str(exc).partition(': ')[2]}") from None


# -- encrypt --------------------------------------------------------------------------------------
def _effective_range(scan: Scan, value_range: Any, modality: str) -> tuple[Any, str, bool]:
    """(value_range for encrypt_volume or None, how it was chosen, whether it is data-independent)."""
    vol = scan.volume
    if value_range is not None:
        return tuple(value_range), "--value-range", True
    code = modality if modality != "auto" else (scan.modality or "").strip().upper() or None
    if code in MODALITY_RANGES:
        how = f"the {code} range" + ("" if modality != "auto" else f" (the file's modality is {code})")
        return MODALITY_RANGES[code], how, True
    if code is not None:
        log.info("%s: modality %s has no fixed value range; using the default", scan.source, code)
    kind = np.dtype(vol.dtype).kind
    if kind in "iub":
        return None, f"the {vol.dtype} range, no modality known (--modality, --value-range)", True
    return None, "the data range", False


def encrypt_input(args: Any) -> tuple[Scan, Any]:
    """Load ``hevr encrypt``'s INPUT, print what it is and the value range it gets; warn (stderr)
    when the data occupy a tiny band of that range. Returns (scan, value_range): the scan brings
    its spacing and patient frame to the store."""
    scan, what = load_scan(
        args.input,
        args.spacing,
        series=args.series,
        volume=args.volume,
        allow_uneven=args.allow_uneven,
        oblique=args.oblique,
    )
    print(f"input:   {what}, spacing {xyz(tuple(scan.spacing)[::-1], sep=', ')}")
    scan = _fill_nan(scan, args.nan_as)
    if scan.frame or scan.modality:
        print(
            f"scan:    {scan.modality or 'modality not recorded'}, "
            f"{'RAS+ patient frame' if scan.frame else 'axes as stored'}, origin "
            f"{', '.join(f'{v:g}' for v in scan.origin)} mm"
        )
    value_range, how, fixed = _effective_range(scan, args.value_range, args.modality)
    if fixed:
        lo, hi = value_range if value_range is not None else default_value_range(scan.volume)
        print(f"values:  density range {lo:g} .. {hi:g}, {how}")
        data_lo, data_hi = minmax(scan.volume)  # one pass over the data
        hint = range_hint(float(data_lo), float(data_hi), (lo, hi))
        if hint:
            warn_line(hint)
    else:
        print(f"values:  density range: {how} (floats without a modality)")
    return scan, value_range


def _nan_count(vol: Any) -> int:
    """NaN voxels of a float volume (one pass), 0 for integers."""
    return int(np.count_nonzero(np.isnan(vol))) if np.dtype(vol.dtype).kind == "f" else 0


def _fill_nan(scan: Scan, value: float | None) -> Scan:
    """The scan with its NaN voxels set to ``value`` (``--nan-as``); refused (exit 2, naming the
    option) when it has NaN voxels and no ``value``. A NaN is no measurement: hevr does not guess one."""
    nans = _nan_count(scan.volume)
    if not nans:
        return scan
    if value is None:
        raise UsageError(
            f"INPUT: expected finite voxel values, got {nans} NaN voxels of {scan.volume.size}; "
            "give them a value with --nan-as VALUE (e.g. --nan-as 0, or the scan's background)"
        )
    vol = scan.volume
    print(f"nan:     {nans} NaN voxels of {vol.size} encrypted as {value:g} (--nan-as)")
    return dataclasses.replace(scan, volume=np.where(np.isnan(vol), np.asarray(value, vol.dtype), vol))


# -- info -------------------------------------------------------------------------------------------
def _values_row(vol: Any, nans: int) -> str:
    """``values`` of ``hevr info``: the range of the finite voxels and how many (``nans``) are NaN."""
    if not nans:
        return f"{vol.min()} .. {vol.max()}"
    if nans == vol.size:
        return f"all {nans} voxels are NaN"
    return f"{np.nanmin(vol)} .. {np.nanmax(vol)}, and {nans} NaN voxels of {vol.size}"


def scan_rows(path: Path, spec: str | None = None, **read: Any) -> list[tuple[str, Any]]:
    """``hevr info`` of a volume file or folder, read as ``hevr encrypt`` reads it with the same
    options (``read``: series, volume, allow_uneven, oblique); a DICOM folder lists its series
    first, and only them when it holds several and ``--series`` names none. ``spec``: an input
    such as ``sample:mri`` that :func:`load_scan` resolves."""
    scan = None
    if spec is not None:  # read once, here
        scan, _ = load_scan(spec, **read)
        path = Path(scan.source)
    rows: list[tuple[str, Any]] = [("path", path)]
    folder = path.is_dir() and not any((path / m).exists() for m in (".zarray", ".zgroup", "zarr.json"))
    dicomdir = path.is_file() and path.name.upper() == "DICOMDIR"
    if (folder or dicomdir) and read.get("series") is None:
        series = list_series(path)
        rows.append(("kind", f"{'DICOMDIR' if dicomdir else 'DICOM folder'}, {len(series)} series"))
        rows += [("series", s.summary()) for s in series]
        if len(series) > 1:
            rows.append(("encrypt", f"one of them: hevr encrypt {path} --series UID ..."))
            return rows
    if scan is None:
        scan, _ = load_scan(str(path), **read)
    vol = scan.volume
    nans = _nan_count(vol)  # one pass, for the values row and the encrypt row
    rows += [
        ("kind", "plaintext volume"),
        ("shape", f"{xyz(vol.shape)} voxels"),
        ("dtype", vol.dtype),
        ("spacing", xyz(tuple(scan.spacing)[::-1], sep=", ")),
        (
            "frame",
            "RAS+ patient frame (+x right, +y anterior, +z superior)"
            if scan.frame
            else "none recorded (axes as stored)",
        ),
        ("origin", ", ".join(f"{v:g}" for v in scan.origin)),
        ("modality", scan.modality or "-"),
        ("values", _values_row(vol, nans)),
    ]
    if min(vol.shape) < 2:  # the rule of encrypt_volume (hevr.core.voxels.check_volume, thick=True)
        rows.append(
            (
                "encrypt",
                "refused: a single slice (an axis of 1 voxel) has no thickness for the rays to "
                "cross; hevr renders volumes (give the folder or file of the whole series)",
            )
        )
        return rows
    if nans:
        rows.append(("encrypt", "needs --nan-as VALUE: hevr encrypts measurements, and a NaN is none"))
        return rows
    value_range, how, fixed = _effective_range(scan, None, "auto")
    if fixed:
        lo, hi = value_range if value_range is not None else default_value_range(vol)
        rows.append(("encrypt", f"density range {lo:g} .. {hi:g} by default ({how})"))
        hint = range_hint(float(vol.min()), float(vol.max()), (lo, hi))
        if hint:
            rows.append(("hint", hint))
    return rows
