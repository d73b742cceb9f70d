"""Reading and writing plaintext volumes.

:func:`load_volume` reads ``.npy``, ``.raw`` (shape and type from the name or arguments),
NRRD (``.nrrd``/``.nhdr``, own reader in :mod:`hevr.volume.nrrd`), NIfTI (``.nii``/``.nii.gz``,
needs nibabel) and DICOM series folders (needs pydicom); the last two come with the
``hevr[io]`` extra. Every reader returns the array in (z, y, x) order (x fastest) and the
spacing in world order (sx, sy, sz), as described in ``API.md``. Voxel axes are kept as
stored: orientation matrices (NRRD space directions, NIfTI affines, DICOM patient
orientation) only contribute their voxel sizes.

:func:`save_volume` writes ``.npy``, ``.raw`` and NRRD (detached ``.nhdr`` + ``.raw``, or
attached ``.nrrd``), enough for tests, demos and the CLI.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import numpy.typing as npt

from .._files import require_file
from .._validate import check_choice, check_spacing, check_volume
from ..errors import ParameterError, VolumeFormatError
from ._optional import require
from .dicom import read_dicom_folder
from .nrrd import (
    check_file,
    is_kind,
    load_raw,
    read_nrrd,
    to_native,
    write_nrrd,
    write_raw,
)
from .rescale import rescale

__all__ = ["load_volume", "save_volume"]

_log = logging.getLogger(__name__)

_Spacing = tuple[float, float, float]

_EXTENSIONS = ".npy, .raw, .nrrd, .nhdr, .nii, .nii.gz or a DICOM series folder"


def _format(path: Path) -> str:
    """Which reader handles ``path``: npy, raw, nrrd, nifti or dicom."""
    if is_kind(path, directory=True):
        return "dicom"
    check_file(path)
    name = path.name.lower()
    if name.endswith((".nii", ".nii.gz")):
        return "nifti"
    suffix = path.suffix.lower()
    if suffix in (".npy", ".raw"):
        return suffix[1:]
    if suffix in (".nrrd", ".nhdr"):
        return "nrrd"
    if suffix in (".dcm", ".dicom", ".ima"):
        raise VolumeFormatError(f"{path.name}: a single DICOM file is not a volume; pass the "
                                f"folder holding the whole series ({path.parent})")
    raise VolumeFormatError(f"{path.name}: unknown volume file extension {suffix or '(none)'!r}; "
                            f"expected {_EXTENSIONS}")


def _check_volume(arr: np.ndarray, path: Path) -> np.ndarray:
    """Reject anything that is not a non-empty 3-D integer/float array; native byte order."""
    return to_native(check_volume(arr, path.name, kinds="uif", error=VolumeFormatError))


def load_volume(path: str | os.PathLike[str], shape: Sequence[int] | None = None,
                dtype: npt.DTypeLike | None = None, spacing: Sequence[float] | None = None,
                byte_order: str = "little") -> tuple[np.ndarray, _Spacing]:
    """Read a 3-D volume from a file or a DICOM series folder.

    Parameters
    ----------
    path : str or os.PathLike
        ``.npy``; ``.raw`` (headerless, x fastest); ``.nrrd``/``.nhdr`` (raw or gzip
        encoding, one data file); ``.nii``/``.nii.gz`` (needs nibabel); or a folder with
        one DICOM series (needs pydicom). The format is chosen by the extension.
    shape : sequence of 3 ints, optional
        Only for ``.raw``: the array shape in (z, y, x) order. Default: parsed from the file
        name, whose ``XxYxZ`` token lists the sizes in x, y, z order (``tooth_103x94x161_uint8.raw``).
    dtype : numpy dtype, optional
        Only for ``.raw``: the voxel type. Default: the name's type token (int8, uint8,
        int16, uint16, int32, uint32, float32 or float64).
    spacing : sequence of 3 floats, optional
        Voxel size (sx, sy, sz) in world order; overrides what the file says. Files without
        spacing (``.npy``, ``.raw``) default to (1, 1, 1).
    byte_order : {"little", "big"}, default "little"
        Only used for ``.raw`` files; the other formats record their byte order.

    Returns
    -------
    volume : numpy.ndarray
        Shape (nz, ny, nx), native byte order, integer or float dtype. Uncompressed native
        data (``.npy``, ``.raw``, raw NRRD) comes as a read-only ``np.memmap``: copy it
        with ``np.array(volume)`` before modifying it. DICOM and scaled NIfTI data are
        rescaled (slope/intercept) and stay integer (int16 or wider, signed) when the
        factors are integers, else become float32.
    spacing : tuple of 3 floats
        (sx, sy, sz).

    Raises
    ------
    FileNotFoundError
        If ``path`` (or an NRRD data file) does not exist.
    VolumeFormatError
        Unknown extension, not 3-D, sizes that do not match the data, truncated files,
        unsupported types or encodings; the message names the file and the problem.
    MissingDependencyError
        NIfTI or DICOM without nibabel/pydicom installed (``pip install 'hevr[io]'``).
    ParameterError
        Invalid ``shape``/``dtype``/``spacing``/``byte_order``, or ``shape``/``dtype``
        given for a format other than ``.raw``.

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
    path = Path(os.fspath(path)).expanduser()
    check_choice("byte_order", byte_order, ("little", "big"))
    override = None if spacing is None else check_spacing(spacing)
    kind = _format(path)
    if kind != "raw" and (shape is not None or dtype is not None):
        raise ParameterError(f"load_volume: shape and dtype only apply to .raw files, got "
                             f"shape={shape!r}, dtype={dtype!r} for {path.name}")
    if kind == "npy":
        vol, file_spacing = _load_npy(path), (1.0, 1.0, 1.0)
    elif kind == "raw":
        vol, file_spacing = load_raw(path, shape, dtype, byte_order), (1.0, 1.0, 1.0)
    elif kind == "nrrd":
        vol, file_spacing = read_nrrd(path)
    elif kind == "nifti":
        vol, file_spacing = _load_nifti(path, need_spacing=override is None)
    else:
        vol, file_spacing = read_dicom_folder(path)
    vol = _check_volume(vol, path)
    if override is None and not all(math.isfinite(v) and v > 0 for v in file_spacing):
        raise VolumeFormatError(f"{path.name}: spacing: expected 3 positive finite voxel sizes in the file, got "
                                f"{tuple(file_spacing)}; pass spacing= to override")
    result = override or file_spacing
    _log.debug("loaded %s: shape %s, %s, spacing %s", path, vol.shape, vol.dtype, result)
    return vol, result


def _load_npy(path: Path) -> np.ndarray:
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise VolumeFormatError(f"{path.name}: not a valid .npy array file ({exc})") from None
    if not isinstance(arr, np.ndarray):  # an .npz archive renamed to .npy
        raise VolumeFormatError(f"{path.name}: expected a single .npy array, got an .npz archive")
    return arr


def _load_nifti(path: Path, need_spacing: bool) -> tuple[np.ndarray, _Spacing]:
    nib = require("nibabel", path)
    try:
        img = nib.load(str(path))
        proxy = img.dataobj
        if nib.is_proxy(proxy):
            # Read unscaled so integral scl_slope/scl_inter keep an integer dtype.
            raw = np.asanyarray(proxy.get_unscaled())
            slope, inter = getattr(proxy, "slope", 1.0), getattr(proxy, "inter", 0.0)
        else:
            raw, slope, inter = np.asanyarray(proxy), 1.0, 0.0
        zooms = img.header.get_zooms()
    except Exception as exc:  # nibabel raises many types for broken files
        raise VolumeFormatError(f"{path.name}: cannot read NIfTI file ({exc})") from None
    shape = tuple(raw.shape)
    while len(shape) > 3 and shape[-1] == 1:  # tools often write (x, y, z, 1)
        shape = shape[:-1]
    if len(shape) != 3:
        raise VolumeFormatError(f"{path.name}: expected a 3-D volume, got a {len(raw.shape)}-D "
                                f"image of shape {raw.shape}")
    if raw.dtype.kind not in "iuf":
        raise VolumeFormatError(f"{path.name}: expected integer or floating-point voxels, "
                                f"got dtype {raw.dtype}")
    vol = rescale(raw.reshape(shape), 1.0 if slope is None else slope, 0.0 if inter is None else inter)
    spacing = tuple(float(z) for z in zooms[:3])
    if need_spacing and not all(math.isfinite(z) and z > 0 for z in spacing):
        raise VolumeFormatError(f"{path.name}: NIfTI voxel sizes (pixdim) must be positive, "
                                f"got {spacing}; pass spacing= to override")
    return vol.transpose(2, 1, 0), spacing  # type: ignore[return-value]


def save_volume(path: str | os.PathLike[str], vol: npt.ArrayLike,
                spacing: Sequence[float] = (1.0, 1.0, 1.0), *, encoding: str = "raw",
                byte_order: str = "little") -> Path:
    """Write a 3-D volume as ``.npy``, ``.raw``, NRRD ``.nhdr`` (+ data file) or ``.nrrd``.

    Parameters
    ----------
    path : str or os.PathLike
        Target; the extension picks the format. ``x.nhdr`` also writes ``x.raw`` (or
        ``x.raw.gz`` with gzip) next to it. Existing files are overwritten.
    vol : array_like
        Integer or floating-point array of shape (nz, ny, nx).
    spacing : sequence of 3 floats, default (1, 1, 1)
        (sx, sy, sz); stored in NRRD ``space directions``. ``.npy`` and ``.raw`` cannot
        store it (a warning is logged when it is not all ones).
    encoding : {"raw", "gzip"}, default "raw"
        NRRD data encoding.
    byte_order : {"little", "big"}, default "little"
        Byte order of ``.raw`` and NRRD data (``.npy`` records its own).

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
    path = Path(os.fspath(path)).expanduser()
    arr = check_volume(np.asanyarray(vol), kinds="uif")
    spacing = check_spacing(spacing)
    check_choice("encoding", encoding, ("raw", "gzip"))
    check_choice("byte_order", byte_order, ("little", "big"))
    require_file(path.parent, "path", "an existing folder", directory=True)
    suffix = path.suffix.lower()
    if suffix in (".nhdr", ".nrrd"):
        write_nrrd(path, arr, spacing, encoding=encoding, byte_order=byte_order)
        return path
    if suffix not in (".npy", ".raw"):
        raise ParameterError(f"save_volume: path must end in .npy, .raw, .nhdr or .nrrd, got {path.name}")
    if encoding != "raw":
        raise ParameterError(f"save_volume: encoding={encoding!r} needs an NRRD file, got {path.name}")
    if spacing != (1.0, 1.0, 1.0):
        _log.warning("save_volume: %s cannot store spacing %s; it will load as (1, 1, 1)",
                     path.name, spacing)
    if suffix == ".npy":
        np.save(path, np.ascontiguousarray(arr), allow_pickle=False)
        return path
    write_raw(path, arr, byte_order)
    return path
