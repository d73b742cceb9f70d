"""NIfTI (``.nii``, ``.nii.gz``) and FreeSurfer MGH (``.mgz``, ``.mgh``) volumes, through nibabel.

Geometry
--------
nibabel's ``img.affine`` maps voxel (i, j, k) to RAS+ millimetres: for NIfTI it is the
sform when ``sform_code > 0``, else the qform (nibabel's choice, the one most tools make);
for MGH the vox2ras matrix. It goes to :func:`hevr.volume.orientation.to_patient_frame`,
which reorders the array as views — not ``nib.as_closest_canonical``, which may copy.
A NIfTI file with ``sform_code == qform_code == 0`` records no orientation (the NIfTI
"method 1" of old ANALYZE files): its axes stay as stored (``frame=None``) with the
``pixdim`` voxel sizes, rather than nibabel's guessed radiological flip.

Values
------
Data are read unscaled; ``scl_slope``/``scl_inter`` are applied by
:func:`hevr.volume.rescale.rescale`, which keeps integer data integer when both are
integers. Unscaled uncompressed ``.nii`` files come back as memory-map views.

Hostile headers
---------------
A ``.nii`` shorter than its header declares is refused before nibabel reads it (nibabel
would allocate the declared size first); a compressed file whose one volume is larger than
this machine's memory is refused before decompressing (:mod:`hevr.volume._memory`).

4-D files
---------
Trailing axes of size 1 are dropped. A 4-D image (fMRI time points, diffusion volumes)
needs ``volume=i``; only that volume is read (``dataobj`` slicing: a view of the memory map
for ``.nii``, a partial decompression for ``.nii.gz``). 5-D and larger images are refused.
NIfTI records no modality, so :attr:`Scan.modality` is None.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CorruptVolumeError, VolumeFormatError
from ._memory import check_fits
from ._optional import require
from ._select import reject_index, select_index
from .orientation import FRAME, to_patient_frame
from .rescale import rescale
from .scan import Scan

__all__ = ["read_nifti"]

_log = logging.getLogger(__name__)


def _unscaled(nib: Any, img: Any, path: Path, index: tuple) -> tuple[np.ndarray, float, float]:
    """The stored values of ``img[index]`` (before scl_slope/scl_inter), the slope and the intercept."""
    proxy = img.dataobj
    if not nib.is_proxy(proxy):
        return np.asanyarray(proxy)[index], 1.0, 0.0
    slope, inter = getattr(proxy, "slope", 1.0), getattr(proxy, "inter", 0.0)
    slope, inter = 1.0 if slope is None else float(slope), 0.0 if inter is None else float(inter)
    if not path.name.lower().endswith((".gz", ".mgz")):  # a memory map: slicing it reads nothing
        return np.asanyarray(proxy.get_unscaled())[index], slope, inter
    getter = getattr(proxy, "_get_unscaled", None)  # nibabel's partial unscaled read (private, 2.x to 5.x)
    if getter is not None:
        return np.asanyarray(getter(index)), slope, inter
    return np.asanyarray(proxy.get_unscaled())[index], slope, inter


def _check_size(nib: Any, img: Any, path: Path, shape: tuple[int, ...], dtype: np.dtype) -> None:
    """Refuse a truncated uncompressed file, or a compressed volume larger than memory, before reading.

    nibabel reads a ``.nii`` too short for its memory map into a buffer of the declared size
    before it notices, and decompresses ``.nii.gz`` into one: a forged header would cost that much.
    """
    offset = getattr(img.dataobj, "offset", None) if nib.is_proxy(img.dataobj) else None
    if path.name.lower().endswith((".gz", ".mgz")):
        check_fits(path.name, shape[:3], dtype, "compressed image data")  # one volume is read
    elif offset is not None:
        need, have = int(offset) + math.prod(shape) * dtype.itemsize, path.stat().st_size
        if have < need:
            raise CorruptVolumeError(
                f"{path.name}: truncated: the header declares shape {shape} of {dtype} "
                f"(data ending at byte {need}), the file holds {have} bytes"
            )


def read_nifti(path: Path, *, volume: int | None = None, oblique: str = "refuse") -> Scan:
    """Read a NIfTI-1/2 or MGH/MGZ file into a :class:`Scan` (RAS+ when the file has an orientation)."""
    nib = require("nibabel", path)
    try:
        img = nib.load(str(path), mmap="r")  # read-only: mapped.file_backed needs it (nibabel maps "c")
    except Exception as exc:  # nibabel raises many types for broken files
        raise VolumeFormatError(f"{path.name}: cannot read NIfTI/MGH file ({exc})") from None
    if not hasattr(img, "affine"):  # CIFTI-2 (greyordinates × series) is no voxel grid
        raise VolumeFormatError(
            f"{path.name}: expected a NIfTI-1/2 or MGH volume on a voxel grid, got a "
            f"{type(img).__name__.replace('Image', '')} file (surface and greyordinate data, "
            "no voxel grid): hevr renders volumes"
        )
    try:
        shape = tuple(int(s) for s in img.shape)
        dtype = np.dtype(img.get_data_dtype())
        affine = np.asarray(img.affine, np.float64)
        zooms = tuple(float(z) for z in img.header.get_zooms()[:3])
    except Exception as exc:  # nibabel raises many types for broken files
        raise VolumeFormatError(f"{path.name}: cannot read NIfTI/MGH file ({exc})") from None
    kept = shape
    while len(kept) > 3 and kept[-1] == 1:  # tools often write (x, y, z, 1)
        kept = kept[:-1]
    if len(kept) not in (3, 4):
        raise VolumeFormatError(
            f"{path.name}: expected a 3-D volume (or a 4-D series with volume=), got a "
            f"{len(shape)}-D image of shape {shape}"
        )
    if dtype.kind not in "iuf":
        raise VolumeFormatError(f"{path.name}: expected integer or floating-point voxels, got dtype {dtype}")
    details: dict[str, Any] = {"format": type(img).__name__}
    index: tuple = (slice(None),) * 3 + (0,) * (len(shape) - 3)
    if len(kept) == 4:
        picked = select_index(volume, kept[3], path)
        index = (slice(None),) * 3 + (picked,) + (0,) * (len(shape) - 4)
        details.update(volume=picked, volumes=kept[3])
    else:
        reject_index(volume, path)
    _check_size(nib, img, path, shape, dtype)
    try:
        raw, slope, inter = _unscaled(nib, img, path, index)
    except Exception as exc:
        raise VolumeFormatError(f"{path.name}: cannot read the image data ({exc})") from None
    vol = rescale(raw, slope, inter).transpose(2, 1, 0)  # (x, y, z) -> (z, y, x), a view
    header = img.header
    codes = [int(header[k]) for k in ("sform_code", "qform_code") if k in header]
    if codes and not any(codes):
        _log.info("%s: no sform/qform (both codes 0): axes kept as stored", path.name)
        return Scan(vol, zooms, (0.0, 0.0, 0.0), None, None, str(path), details)  # type: ignore[arg-type]
    if not all(math.isfinite(v) for v in affine.ravel()):
        raise VolumeFormatError(f"{path.name}: the image's affine is not finite: {affine.tolist()}")
    vol, spacing, origin = to_patient_frame(vol, affine, name=path.name, oblique=oblique)
    return Scan(vol, spacing, origin, FRAME, None, str(path), details)
