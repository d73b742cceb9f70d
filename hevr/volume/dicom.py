"""DICOM volumes as a radiologist's files come (needs pydicom, the ``hevr[io]`` extra).

:func:`read_dicom` reads one series from a folder tree, a ``DICOMDIR`` or a single file,
in hevr's RAS+ patient frame (:mod:`hevr.volume.orientation`):

1. find the images and pick the series, from headers only (:mod:`hevr.volume.dicom_series`);
2. list its frames with their geometry (single-frame slices, enhanced and legacy
   multi-frame files alike) and stack them along the slice normal, refusing duplicate
   positions, uneven gaps (unless ``allow_uneven``), gantry tilt (unless ``oblique="snap"``)
   and mixed orientations (:mod:`hevr.volume.dicom_frames`, :mod:`hevr.volume.dicom_stack`);
3. refuse a series larger than this machine's memory (:mod:`hevr.volume._memory`: compressed
   pixel data is decoded into one array of the declared size), then decode the pixels of that
   series only, rescale them per frame (``RescaleSlope/Intercept``, integer-preserving,
   :func:`~hevr.volume.rescale.rescale`);
4. turn the voxel→LPS+ affine into RAS+ (``LPS_TO_RAS @ affine``) and reorient the array
   with :func:`~hevr.volume.orientation.to_patient_frame` (a view: transposes and flips only).

Without ``ImagePositionPatient``/``ImageOrientationPatient`` (or with a non-positive
``PixelSpacing``, then passed on as recorded for the caller to reject or override) the
slices are ordered by ``InstanceNumber``, the axes kept as stored and ``Scan.frame`` is None.
Colour images (``SamplesPerPixel`` ≠ 1, palette colour) are refused: they are pictures, not
densities.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.validate import check_choice
from ..errors import CorruptVolumeError, MissingDependencyError, VolumeFormatError
from ._memory import check_fits
from ._optional import require
from .dicom_frames import Frame, frames_of
from .dicom_mosaic import untile
from .dicom_series import Image, SeriesInfo, choose_series, list_series, scan_images
from .dicom_stack import plan_stack
from .orientation import FRAME, LPS_TO_RAS, to_patient_frame
from .rescale import rescale
from .scan import Scan

__all__ = ["SeriesInfo", "list_series", "read_dicom", "read_dicom_folder"]

_log = logging.getLogger(__name__)

_Spacing = tuple[float, float, float]


def read_dicom(
    path: str | os.PathLike[str], *, series: str | None = None, allow_uneven: bool = False, oblique: str = "refuse"
) -> Scan:
    """Read one DICOM series as a volume in the RAS+ patient frame.

    Parameters
    ----------
    path : str or os.PathLike
        A folder (searched recursively; non-DICOM and hidden files are skipped), a
        ``DICOMDIR`` file (its referenced images), or one DICOM file: a multi-frame file is
        a volume by itself, a single-frame file stands for its series in the same folder.
    series : str, optional
        Which series, when ``path`` holds several: a SeriesInstanceUID, a SeriesNumber
        (``"3"``, when unique) or a unique prefix of a UID. Without it, several series are
        refused with a listing (also available from :func:`list_series`).
    allow_uneven : bool, default False
        Stack slices whose gaps differ by more than 1 % (or with a missing slice) at the
        median gap instead of refusing them; distances along the slice axis become wrong.
    oblique : {"refuse", "snap"}, default "refuse"
        Oblique planes and gantry-tilted (sheared) stacks: refuse them, or take the nearest
        patient axes without resampling (logged with the angle).

    Returns
    -------
    Scan
        ``volume`` (nz, ny, nx) in RAS+ order (a view of the stacked array), ``spacing``
        (sx, sy, sz) in mm, ``origin`` (RAS+ mm of voxel 0), ``frame`` ("RAS", or None
        without patient geometry), ``modality`` and ``details`` (``series_uid``,
        ``series_number``, ``series_description``, ``images``, ``frames``,
        ``transfer_syntax``, ``uneven_spacing``).

    Raises
    ------
    MissingFileError
        ``path`` does not exist.
    VolumeFormatError
        No image, several series and no (or no matching) ``series``, mixed sizes or
        orientations, duplicate positions, uneven spacing, tilt, colour images, pixel data
        that cannot be decoded; the message names the file.
    ParameterError
        ``oblique`` is not "refuse" or "snap".
    MissingDependencyError
        pydicom is not installed.
    """
    path = Path(path)
    check_choice("oblique", oblique, ("refuse", "snap"))
    pydicom = require("pydicom", path)
    name = path.name
    uid, images = choose_series(name, scan_images(path), series)
    try:
        _check_images(images)
        frames = [fr for im in images for fr in frames_of(im)]
        _check_layout(frames, name)
        stack = plan_stack(frames, name, allow_uneven=allow_uneven, oblique=oblique)
        frames = [frames[i] for i in stack.order]
        first = images[0].header
        check_fits(
            name,
            (len(frames), *(max(1, v) for v in frames[0].shape), -(-_positive(first, "BitsAllocated") // 8)),
            np.uint8,
            "DICOM pixel data",
        )
        raw = _decode(pydicom, frames)
    except (VolumeFormatError, CorruptVolumeError) as exc:
        if path.is_dir() or len(images) < 2:
            raise
        raise type(exc)(
            f"{exc} [{name} is one slice of series {uid or '?'}: a single-frame DICOM file stands "
            f"for its series, so the {len(images) - 1} other files of it in {path.parent} were read "
            f"too; to read {name} alone, put it in a folder of its own]"
        ) from None
    slopes, inters = [f.slope for f in frames], [f.intercept for f in frames]
    if len(set(slopes)) == 1 and len(set(inters)) == 1:  # one factor: the cheaper whole-array path
        slopes, inters = slopes[:1], inters[:1]
    vol = rescale(raw, slopes, inters)
    meta = getattr(first, "file_meta", None) or {}
    details: dict[str, Any] = {
        "series_uid": uid,
        "series_number": _text(first.get("SeriesNumber")),
        "series_description": _text(first.get("SeriesDescription")),
        "images": len(images),
        "frames": len(frames),
        "transfer_syntax": _text(meta.get("TransferSyntaxUID")),
        "uneven_spacing": stack.uneven,
    }
    modality = _text(first.get("Modality")) or None
    if stack.affine is None:
        return Scan(vol, stack.spacing, frame=None, modality=modality, source=str(path), details=details)
    view, spacing, origin = to_patient_frame(vol, LPS_TO_RAS @ stack.affine, name=name, oblique=oblique)
    _log.debug("%s: series %s, %d frame(s), %s, spacing %s", name, uid, len(frames), modality, spacing)
    return Scan(view, spacing, origin, FRAME, modality, str(path), details)


def read_dicom_folder(folder: Path) -> tuple[np.ndarray, _Spacing]:
    """``read_dicom(folder)`` as (volume, spacing): the form :func:`hevr.load_volume` used."""
    scan = read_dicom(folder)
    return scan.volume, scan.spacing


def _positive(ds: Any, key: str) -> int:
    """A positive integer attribute, else 1 (pydicom's decoder reports the invalid value)."""
    try:
        return max(1, int(ds.get(key)))
    except (TypeError, ValueError):
        return 1


def _text(value: Any) -> str:
    return "" if value is None else str(value).strip()


def _check_images(images: list[Image]) -> None:
    """One image size and greyscale samples throughout the series."""
    first = images[0].header
    size = (first.get("Rows"), first.get("Columns"))
    for im in images:
        ds = im.header
        spp, photometric = ds.get("SamplesPerPixel", 1), _text(ds.get("PhotometricInterpretation"))
        if spp not in (1, None) or photometric.startswith(("RGB", "YBR", "PALETTE")):
            raise VolumeFormatError(
                f"{im.path.name}: expected greyscale images (SamplesPerPixel 1, MONOCHROME), "
                f"got colour ({spp} sample(s) per pixel, {photometric or '?'}); a colour "
                "picture is not a density volume"
            )
        if (ds.get("Rows"), ds.get("Columns")) != size:
            raise VolumeFormatError(
                f"{im.path.name}: slice size {ds.get('Rows')}x{ds.get('Columns')} differs "
                f"from {size[0]}x{size[1]} in {images[0].path.name}"
            )


def _check_layout(frames: list[Frame], name: str) -> None:
    """One slice layout throughout: all Siemens MOSAICs of one tiling, or none."""
    layouts = {None if f.mosaic is None else (f.mosaic.slices, f.mosaic.grid) for f in frames}
    if len(layouts) > 1:
        what = [
            f"{f.image.path.name}: " + ("not a mosaic" if f.mosaic is None else f"a mosaic of {f.mosaic.slices} slices")
            for f in frames
        ]
        raise VolumeFormatError(
            f"{name}: expected one slice layout for the whole series, got {'; '.join(sorted(set(what))[:2])}"
        )


def _decode(pydicom: Any, frames: list[Frame]) -> np.ndarray:
    """The stored values of ``frames``, stacked in that order; each file decoded once."""
    slots: dict[Path, list[tuple[int, int]]] = {}
    for k, f in enumerate(frames):
        slots.setdefault(f.image.path, []).append((k, f.index))
    out: np.ndarray | None = None
    for file, pairs in slots.items():
        image = frames[pairs[0][0]].image
        try:
            ds = pydicom.dcmread(file)
            arr = ds.pixel_array
        except Exception as exc:  # noqa: BLE001  # compressed syntaxes need handlers that may be missing
            meta = getattr(image.header, "file_meta", None) or {}
            syntax = meta.get("TransferSyntaxUID", "?")
            text = str(exc)
            if "missing dependencies" in text:  # pydicom has decoders for it, none installed: exit 1, not 2
                needs = "; ".join(line.strip() for line in text.splitlines()[1:] if line.strip())
                raise MissingDependencyError(
                    f"{file.name}: decoding its pixel data (transfer syntax {syntax}) needs "
                    f"a pydicom plugin that is not installed — one of: {needs}"
                ) from None
            text = " ".join(line.strip() for line in text.splitlines() if line.strip())  # one line for the CLI
            hint = (
                (
                    "; another pydicom plugin (pylibjpeg with its libjpeg/openjpeg packages, or python-gdcm) "
                    "may decode it"
                )
                if "all available plugins" in text
                else ""
            )
            raise CorruptVolumeError(
                f"{file.name}: cannot decode the pixel data (transfer syntax {syntax}): {text}{hint}"
            ) from None
        rows, cols = int(image.header.Rows), int(image.header.Columns)
        if arr.size != image.frames * rows * cols:
            raise CorruptVolumeError(
                f"{file.name}: expected {image.frames} frame(s) of {rows}x{cols} pixels, "
                f"got pixel data of shape {arr.shape}"
            )
        mosaic = frames[pairs[0][0]].mosaic
        if mosaic is not None:  # one image of tiles: its slices
            arr = untile(arr.reshape(rows, cols), mosaic)
            rows, cols = mosaic.rows, mosaic.columns
        arr = arr.reshape(-1, rows, cols)
        if out is None:
            out = np.empty((len(frames), rows, cols), arr.dtype)
        elif np.result_type(out.dtype, arr.dtype) != out.dtype:
            out = out.astype(np.result_type(out.dtype, arr.dtype))
        dest, src = zip(*pairs)
        out[list(dest)] = arr[list(src)]
    assert out is not None
    return out
