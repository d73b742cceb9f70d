"""Reading and writing plaintext volumes; one dispatcher for every scan format.

:func:`read_scan` reads a file or folder into a :class:`hevr.volume.scan.Scan`; the format
comes from the name (and, for folders, what they hold):

=========================================  =====================================================
``.npy``, ``.raw``                         numpy / headerless (:mod:`hevr.volume.raw`); axes as stored, ``frame=None``
``.nrrd``, ``.nhdr``                       :mod:`hevr.volume.nrrd` + :mod:`hevr.volume.nrrd_space`
``.nii``, ``.nii.gz``, ``.mgz``, ``.mgh``  nibabel (:mod:`hevr.volume.nifti`)
``.tif``, ``.tiff`` (OME-TIFF, ImageJ)     tifffile (:mod:`hevr.volume.tiff`)
folder with ``zarr.json``/``.zarray``/…    zarr / OME-Zarr (:mod:`hevr.volume.zarr_input`)
other folder, ``DICOMDIR``, ``.dcm`` …     pydicom (:mod:`hevr.volume.dicom`)
=========================================  =====================================================

Files that record patient geometry (NRRD with an anatomical ``space``, NIfTI/MGH affines,
DICOM) come back reoriented into hevr's RAS+ patient frame (:mod:`hevr.volume.orientation`:
transposes and flips only, memory maps stay memory maps); the others keep their stored
axes. Every reader returns (z, y, x) order (x fastest) and the spacing in world order
(sx, sy, sz). :func:`load_volume` is :func:`read_scan` reduced to ``(volume, spacing)``.

:func:`save_volume` writes ``.npy``, ``.raw`` and NRRD (detached ``.nhdr`` + ``.raw``, or
attached ``.nrrd``), enough for tests, demos and the CLI.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..core.files import check_regular, require_file, write_file
from ..core.validate import check_bool, check_choice, check_int, check_spacing
from ..core.voxels import check_volume
from ..errors import MissingFileError, ParameterError, VolumeFormatError
from .dicom import read_dicom
from .nifti import read_nifti
from .nrrd import write_nrrd
from .nrrd_space import read_nrrd_scan
from .raw import check_file, data_parts, is_kind, load_raw, to_native, write_raw
from .scan import Scan
from .tiff import read_tiff
from .zarr_input import is_zarr, read_zarr

__all__ = ["read_scan", "load_volume", "save_volume"]

_log = logging.getLogger(__name__)

_Spacing = tuple[float, float, float]

_EXTENSIONS = (
    ".npy, .raw, .nrrd, .nhdr, .nii, .nii.gz, .mgz, .mgh, .tif, .tiff, .dcm, DICOMDIR, a DICOM "
    "folder or a Zarr/OME-Zarr folder"
)
_DICOM_SUFFIXES = (".dcm", ".dicom", ".ima")
_MULTI = ("nifti", "nrrd", "zarr", "tiff")  # formats that may hold several volumes (volume=)


def _format(path: Path) -> str:
    """Which reader handles ``path``: npy, raw, nrrd, nifti, tiff, zarr or dicom."""
    if is_kind(path, directory=True):
        return "zarr" if is_zarr(path) else "dicom"
    check_file(path)
    name = path.name.lower()
    if name.endswith((".nii", ".nii.gz", ".mgz", ".mgh")):
        return "nifti"
    suffix = path.suffix.lower()
    if suffix in (".npy", ".raw"):
        return suffix[1:]
    if suffix in (".nrrd", ".nhdr"):
        return "nrrd"
    if suffix in (".tif", ".tiff"):
        return "tiff"
    if suffix in _DICOM_SUFFIXES or path.name.upper() == "DICOMDIR":
        return "dicom"
    raise VolumeFormatError(
        f"{path.name}: unknown volume file extension {suffix or '(none)'!r}; expected {_EXTENSIONS}"
    )


def _check_volume(arr: np.ndarray, path: Path) -> np.ndarray:
    """Reject anything that is not a non-empty 3-D integer/float array; native byte order."""
    return to_native(check_volume(arr, path.name, kinds="uif", error=VolumeFormatError))


def _check_folder_files(folder: Path) -> None:
    """Every file in the Zarr input ``folder`` is a regular file: a FIFO, a socket or a device
    in place of a chunk or a document would block or fail Zarr's read (one ``stat`` each)."""
    for root, _, files in os.walk(folder):
        for f in files:
            try:
                check_regular(
                    Path(root) / f, "path", f"a file of the Zarr input {folder.name}", error=VolumeFormatError
                )
            except MissingFileError:  # removed while we looked: Zarr says what that means
                continue


def _check_keywords(
    kind: str, path: Path, shape: Any, dtype: Any, series: Any, allow_uneven: Any, volume: Any
) -> int | None:
    """Refuse keywords that do not apply to ``kind``; return ``volume`` checked."""
    if kind != "raw" and (shape is not None or dtype is not None):
        raise ParameterError(
            f"load_volume: shape and dtype only apply to .raw files, got "
            f"shape={shape!r}, dtype={dtype!r} for {path.name}"
        )
    if kind != "dicom" and (series is not None or allow_uneven):
        raise ParameterError(
            f"read_scan: series and allow_uneven only apply to DICOM, got series={series!r}, "
            f"allow_uneven={allow_uneven!r} for {path.name}"
        )
    if volume is None:
        return None
    if kind not in _MULTI:
        raise ParameterError(
            f"volume: only applies to 4-D NIfTI/MGH, NRRD, TIFF or OME-Zarr files, got "
            f"volume={volume!r} for {path.name}"
        )
    return check_int("volume", volume, 0)


def read_scan(
    path: str | os.PathLike[str],
    *,
    shape: Sequence[int] | None = None,
    dtype: npt.DTypeLike | None = None,
    spacing: Sequence[float] | None = None,
    byte_order: str = "little",
    series: str | None = None,
    volume: int | None = None,
    allow_uneven: bool = False,
    oblique: str = "refuse",
) -> Scan:
    """Read a 3-D scan from a file or folder, in hevr's RAS+ patient frame when the file has one.

    Parameters
    ----------
    path : str or os.PathLike
        A file or folder; see the table in :mod:`hevr.volume.loaders`. The format is chosen
        by the extension, folders by their content (Zarr metadata, else DICOM).
    shape, dtype : optional
        Only for ``.raw``: the array shape in (z, y, x) order and the voxel type. Default:
        the name's ``XxYxZ`` token (sizes in x, y, z order) and type token
        (``tooth_103x94x161_uint8.raw``).
    spacing : sequence of 3 floats, optional
        Voxel size (sx, sy, sz) in world order; overrides what the file says. Files without
        spacing (``.npy``, ``.raw``, plain TIFF and Zarr arrays) default to (1, 1, 1).
    byte_order : {"little", "big"}, default "little"
        Only used for ``.raw`` files; the other formats record their byte order.
    series : str, optional
        DICOM only: the SeriesInstanceUID (or a unique prefix) to read from a folder holding several.
    volume : int, optional
        The index along a 4th dimension (NIfTI/MGH time points, NRRD time or component
        axis, TIFF ``T``, OME-Zarr ``t``). Required when that dimension holds more than one;
        refused for 3-D files.
    allow_uneven : bool, default False
        DICOM only: accept unevenly spaced slices (read at their median spacing).
    oblique : {"refuse", "snap"}, default "refuse"
        A scan whose axes are more than 1° off the patient axes is refused, or snapped to the
        nearest axes with ``"snap"`` (see :func:`hevr.volume.orientation.to_patient_frame`).

    Returns
    -------
    Scan
        ``volume`` of shape (nz, ny, nx), native byte order, integer or float; ``spacing``;
        ``origin``; ``frame`` (``"RAS"`` or None); ``modality``; ``source``; ``details``.
        Uncompressed native data (``.npy``, ``.raw``, raw NRRD, ``.nii``, plain TIFF stacks)
        comes as a read-only ``np.memmap`` (possibly a transposed/flipped view of one):
        copy it with ``np.array(volume)`` before modifying it. Zarr inputs are read into
        memory. DICOM and scaled NIfTI data are rescaled (slope/intercept) and stay integer
        (int16 or wider, signed) when the factors are integers, else become float32.

    Raises
    ------
    FileNotFoundError
        If ``path`` (or an NRRD data file) does not exist.
    VolumeFormatError
        Unknown extension, not 3-D (or a 4-D file without ``volume=``), sizes that do not
        match the data, truncated files, unsupported types or encodings, RGB/multi-channel
        data, oblique scans, encrypted hevr stores; the message names the file.
    MissingDependencyError
        NIfTI/MGH, DICOM, TIFF or NRRD ascii without nibabel/pydicom/tifffile/pynrrd
        (``pip install 'hevr[io]'``).
    ParameterError
        Invalid arguments, or arguments given for a format they do not apply to.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from hevr.volume.loaders import read_scan, save_volume
    >>> p = save_volume(os.path.join(tempfile.mkdtemp(), "v.nhdr"), np.zeros((4, 5, 6), np.int16), (0.5, 1, 2))
    >>> scan = read_scan(p)
    >>> scan.volume.shape, scan.spacing, scan.frame
    ((4, 5, 6), (0.5, 1.0, 2.0), None)
    """
    path = _as_path(path)
    check_choice("byte_order", byte_order, ("little", "big"))
    check_choice("oblique", oblique, ("refuse", "snap"))
    if not isinstance(allow_uneven, (bool, np.bool_)):  # "no" is truthy: it would allow them
        raise ParameterError(f"allow_uneven: expected True or False, got {allow_uneven!r}")
    override = None if spacing is None else check_spacing(spacing)
    kind = _format(path)
    if kind == "zarr":
        _check_folder_files(path)
    volume = _check_keywords(kind, path, shape, dtype, series, allow_uneven, volume)
    if kind == "npy":
        scan = Scan(_load_npy(path), (1.0, 1.0, 1.0), source=str(path))
    elif kind == "raw":
        scan = Scan(load_raw(path, shape, dtype, byte_order), (1.0, 1.0, 1.0), source=str(path))
    elif kind == "nrrd":
        scan = read_nrrd_scan(path, volume=volume, oblique=oblique)
    elif kind == "nifti":
        scan = read_nifti(path, volume=volume, oblique=oblique)
    elif kind == "tiff":
        scan = read_tiff(path, volume=volume)
    elif kind == "zarr":
        scan = read_zarr(path, volume=volume)
    else:
        scan = read_dicom(path, series=series, allow_uneven=allow_uneven, oblique=oblique)
    vol = _check_volume(scan.volume, path)
    sx, sy, sz = scan.spacing
    file_spacing = (float(sx), float(sy), float(sz))
    if override is None and not all(math.isfinite(v) and v > 0 for v in file_spacing):
        raise VolumeFormatError(
            f"{path.name}: spacing: expected 3 positive finite voxel sizes in the file, got "
            f"{file_spacing}; pass spacing= to override"
        )
    result = override or file_spacing
    _log.debug("loaded %s: shape %s, %s, spacing %s, frame %s", path, vol.shape, vol.dtype, result, scan.frame)
    return dataclasses.replace(scan, volume=vol, spacing=result)


def load_volume(
    path: str | os.PathLike[str],
    shape: Sequence[int] | None = None,
    dtype: npt.DTypeLike | None = None,
    spacing: Sequence[float] | None = None,
    byte_order: str = "little",
    *,
    series: str | None = None,
    volume: int | None = None,
    allow_uneven: bool = False,
    oblique: str = "refuse",
) -> tuple[np.ndarray, _Spacing]:
    """Read a 3-D volume: :func:`read_scan` reduced to ``(volume, spacing)``.

    Files with patient geometry come back in hevr's RAS+ frame (NRRD with an anatomical
    ``space``, NIfTI/MGH, DICOM: transposed/flipped views of what the file stores, e.g. an
    LPS NRRD with identity directions has its x and y axes reversed); ``.npy``, ``.raw``,
    TIFF, Zarr and NRRD without ``space`` keep their stored axes. Use :func:`read_scan` to
    also get the origin, frame and modality.

    Parameters
    ----------
    path, shape, dtype, spacing, byte_order, series, volume, allow_uneven, oblique
        As for :func:`read_scan`.

    Returns
    -------
    volume : numpy.ndarray
        Shape (nz, ny, nx), native byte order, integer or float dtype; a read-only
        ``np.memmap`` (or a view of one) for uncompressed native data.
    spacing : tuple of 3 floats
        (sx, sy, sz).

    Raises
    ------
    FileNotFoundError, VolumeFormatError, MissingDependencyError, ParameterError
        As for :func:`read_scan`.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from hevr.volume.loaders import load_volume, save_volume
    >>> d = tempfile.mkdtemp()
    >>> _ = save_volume(os.path.join(d, "v.nhdr"), np.zeros((4, 5, 6), np.int16), (0.5, 1, 2))
    >>> vol, spacing = load_volume(os.path.join(d, "v.nhdr"))
    >>> vol.shape, vol.dtype, spacing
    ((4, 5, 6), dtype('int16'), (0.5, 1.0, 2.0))
    """
    scan = read_scan(
        path,
        shape=shape,
        dtype=dtype,
        spacing=spacing,
        byte_order=byte_order,
        series=series,
        volume=volume,
        allow_uneven=allow_uneven,
        oblique=oblique,
    )
    return scan.volume, scan.spacing


def _as_path(path: Any) -> Path:
    """``path`` as a :class:`~pathlib.Path` (``~`` expanded); anything but a str/PathLike is refused."""
    if isinstance(path, bytes) or not isinstance(path, (str, os.PathLike)):
        raise ParameterError(f"path: expected a file or folder name (str or os.PathLike), got {type(path).__name__}")
    return Path(os.fspath(path)).expanduser()


def _load_npy(path: Path) -> np.ndarray:
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise VolumeFormatError(f"{path.name}: not a valid .npy array file ({exc})") from None
    if not isinstance(arr, np.ndarray):  # an .npz archive renamed to .npy
        raise VolumeFormatError(f"{path.name}: expected a single .npy array, got an .npz archive")
    return arr


def save_volume(
    path: str | os.PathLike[str],
    vol: npt.ArrayLike,
    spacing: Sequence[float] = (1.0, 1.0, 1.0),
    *,
    encoding: str = "raw",
    byte_order: str = "little",
    overwrite: bool = False,
) -> Path:
    """Write a 3-D volume as ``.npy``, ``.raw``, NRRD ``.nhdr`` (+ data file) or ``.nrrd``.

    Parameters
    ----------
    path : str or os.PathLike
        Target; the extension picks the format. ``x.nhdr`` also writes ``x.raw`` (or
        ``x.raw.gz`` with gzip) next to it. Every file is written atomically (through a
        temporary sibling) and an existing one is never replaced unless ``overwrite=True``.
    vol : array_like
        Integer or floating-point array of shape (nz, ny, nx).
    spacing : sequence of 3 floats, default (1, 1, 1)
        (sx, sy, sz); stored in NRRD ``space directions``. ``.npy`` and ``.raw`` cannot
        store it (a warning is logged when it is not all ones).
    encoding : {"raw", "gzip"}, default "raw"
        NRRD data encoding.
    byte_order : {"little", "big"}, default "little"
        Byte order of ``.raw`` and NRRD data (``.npy`` records its own).
    overwrite : bool, default False
        Replace existing files (else :class:`hevr.ExistingFileError`, nothing written).

    Returns
    -------
    pathlib.Path
        The path written (the header for ``.nhdr``).

    Raises
    ------
    ParameterError
        Bad array, spacing, encoding, byte order or extension, or a ``.raw`` name whose
        ``XxYxZ``/type tokens contradict the array.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from hevr.volume.loaders import load_volume, save_volume
    >>> p = save_volume(os.path.join(tempfile.mkdtemp(), "v.npy"), np.ones((2, 3, 4)))
    >>> load_volume(p)[0].shape
    (2, 3, 4)
    """
    path = _as_path(path)
    arr = check_volume(np.asanyarray(vol), kinds="uif")
    spacing = check_spacing(spacing)
    check_choice("encoding", encoding, ("raw", "gzip"))
    check_choice("byte_order", byte_order, ("little", "big"))
    overwrite = check_bool("overwrite", overwrite)
    require_file(path.parent, "path", "an existing folder", directory=True)
    suffix = path.suffix.lower()
    if suffix in (".nhdr", ".nrrd"):
        write_nrrd(path, arr, spacing, encoding=encoding, byte_order=byte_order, overwrite=overwrite)
        return path
    if suffix not in (".npy", ".raw"):
        raise ParameterError(f"save_volume: path must end in .npy, .raw, .nhdr or .nrrd, got {path.name}")
    if encoding != "raw":
        raise ParameterError(f"save_volume: encoding={encoding!r} needs an NRRD file, got {path.name}")
    if spacing != (1.0, 1.0, 1.0):
        _log.warning("save_volume: %s cannot store spacing %s; it will load as (1, 1, 1)", path.name, spacing)
    if suffix == ".npy":
        head = io.BytesIO()  # C order whatever arr's layout: data_parts writes x fastest
        np.lib.format.write_array_header_1_0(
            head, {"descr": np.lib.format.dtype_to_descr(arr.dtype), "fortran_order": False, "shape": arr.shape}
        )
        write_file(
            path,
            itertools.chain([head.getvalue()], data_parts(arr, None, "raw")),
            overwrite=overwrite,
            doing="writing the volume",
        )
        return path
    write_raw(path, arr, byte_order, overwrite=overwrite)
    return path
