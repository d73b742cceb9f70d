"""Siemens MOSAIC images: many slices tiled in one DICOM frame (needs nibabel for the CSA header).

Siemens scanners store an EPI, diffusion or fMRI volume as one 2-D image whose
``ImageType`` contains ``MOSAIC``: the n slices of r × c pixels are tiles of an m × m grid,
m = ⌈√n⌉, row-major (slice k in grid row ⌊k/m⌋, column k mod m), the unused tiles black.
The image is R × C = (m·r) × (m·c) pixels. n is in the private Siemens CSA image header
(element (0029,1010), field ``NumberOfImagesInMosaic``), which nibabel's ``csareader``
parses; the header also holds ``SliceNormalVector``, the direction in which the slices follow
each other.

Geometry. ``ImagePositionPatient`` (IPP) of a mosaic is not that of any slice: it is the
position of the first pixel of the whole R × C image laid over the field of view, whose centre
is the centre of every tile. With row direction x = IOP[:3] (along columns), column direction
y = IOP[3:] (along rows) and ``PixelSpacing`` (Δr, Δc), the first pixel of slice 0 therefore
lies at

    p₀ = IPP + ((C − c)/2)·Δc·x + ((R − r)/2)·Δr·y,

and slice k at p₀ + k·g·n̂, with n̂ the CSA ``SliceNormalVector`` (else x × y) and g the
``SpacingBetweenSlices`` (else ``SliceThickness``). Each tile then becomes an ordinary frame
(:class:`~hevr.volume.dicom_frames.Frame`), so ordering, spacing and tilt checks are those of
any series. A diffusion or fMRI series holds one mosaic per direction or time point at the
same positions: name one file to read that volume.

A mosaic whose pixel data cannot hold its tiles (R or C not a multiple of m), or whose CSA
header is missing or unreadable, is refused: read as one slice it would be a plausible wrong
volume.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CorruptVolumeError, VolumeFormatError
from ._optional import require

__all__ = ["Mosaic", "is_mosaic", "mosaic_of", "tile_position", "untile"]


@dataclass(frozen=True)
class Mosaic:
    """How one mosaic image holds its slices (see the module docstring)."""

    slices: int  # n, from the CSA header
    grid: int  # m = ceil(sqrt(n)) tiles per side
    rows: int  # r, of one slice
    columns: int  # c, of one slice
    normal: tuple[float, float, float] | None  # CSA SliceNormalVector (None: IOP's cross product)


def is_mosaic(ds: Any) -> bool:
    """Whether a header's ``ImageType`` says MOSAIC (no CSA parsing).

    >>> is_mosaic({"ImageType": ["ORIGINAL", "PRIMARY", "M", "ND", "MOSAIC"]}), is_mosaic({})
    (True, False)
    """
    kind = ds.get("ImageType")
    if kind is None:
        return False
    values = [kind] if isinstance(kind, str) else list(kind)
    return any(str(v).strip().upper() == "MOSAIC" for v in values)


def grid_of(slices: int) -> int:
    """Tiles per side of a mosaic of ``slices`` slices.

    >>> grid_of(48), grid_of(49), grid_of(1)
    (7, 7, 1)
    """
    return math.isqrt(slices - 1) + 1


def mosaic_of(ds: Any, path: Path) -> Mosaic | None:
    """The mosaic layout of a header, or None when it is no mosaic.

    Raises
    ------
    VolumeFormatError
        ``ImageType`` says MOSAIC but the CSA header does not say how many slices, or the
        image size is no m × m grid of equal tiles.
    MissingDependencyError
        nibabel (which reads the CSA header) is not installed.
    """
    if not is_mosaic(ds):
        return None
    with warnings.catch_warnings():  # nibabel.nicom warns about its own DICOM readers, which hevr does not use
        warnings.filterwarnings("ignore", message="The DICOM readers are highly experimental")
        csareader = require("nibabel.nicom.csareader", path)
    name = path.name
    try:
        csa = csareader.get_csa_header(ds, "image")
        n = csareader.get_n_mosaic(csa) if csa else None
        normal = csareader.get_slice_normal(csa) if csa else None
    except Exception as exc:  # noqa: BLE001  # a damaged private header: nibabel raises several types
        raise VolumeFormatError(
            f"{name}: a Siemens MOSAIC whose CSA image header (0029,1010) cannot be "
            f"read ({exc}); expected it to say how many slices the mosaic holds"
        ) from None
    try:
        n = 0 if n is None else int(n)
    except (TypeError, ValueError):
        n = 0
    if n < 1:
        raise VolumeFormatError(
            f"{name}: a Siemens MOSAIC (ImageType): expected NumberOfImagesInMosaic in "
            f"its CSA image header (0029,1010), got {'none' if not n else n}"
        )
    rows, cols, m = int(ds.get("Rows") or 0), int(ds.get("Columns") or 0), grid_of(n)
    if rows < m or cols < m or rows % m or cols % m:
        raise CorruptVolumeError(
            f"{name}: a Siemens MOSAIC of {n} slices on a {m}x{m} grid: expected rows and "
            f"columns that are multiples of {m}, got {rows}x{cols} pixels (pixel data "
            "that cannot hold the slices it declares)"
        )
    vec = None
    if normal is not None:
        v = np.asarray(normal, np.float64).ravel()
        if v.size == 3 and np.all(np.isfinite(v)) and abs(np.linalg.norm(v) - 1) < 1e-2:
            x, y, z = (float(c) for c in v / np.linalg.norm(v))
            vec = (x, y, z)
    return Mosaic(n, m, rows // m, cols // m, vec)


def tile_position(
    mosaic: Mosaic, ipp: tuple[float, ...], iop: tuple[float, ...], pixel_spacing: tuple[float, ...], gap: float, k: int
) -> tuple[float, ...]:
    """``ImagePositionPatient`` of slice ``k`` (the formula of the module docstring).

    >>> m = Mosaic(4, 2, 2, 2, (0.0, 0.0, 1.0))
    >>> tile_position(m, (0.0, 0.0, 0.0), (1, 0, 0, 0, 1, 0), (1.0, 1.0), 3.0, 1)
    (1.0, 1.0, 3.0)
    """
    x, y = np.asarray(iop[:3], np.float64), np.asarray(iop[3:], np.float64)
    normal = np.asarray(mosaic.normal) if mosaic.normal is not None else np.cross(x, y)
    big_r, big_c = mosaic.rows * mosaic.grid, mosaic.columns * mosaic.grid
    p0 = (
        np.asarray(ipp, np.float64)
        + (big_c - mosaic.columns) / 2 * pixel_spacing[1] * x
        + (big_r - mosaic.rows) / 2 * pixel_spacing[0] * y
    )
    return tuple(float(v) for v in p0 + k * gap * normal)


def untile(arr: np.ndarray, mosaic: Mosaic) -> np.ndarray:
    """The (n, r, c) slices of one mosaic image (R, C): tiles row-major, unused ones dropped.

    >>> a = np.arange(16).reshape(4, 4)
    >>> untile(a, Mosaic(3, 2, 2, 2, None))[:, 0, :].tolist()
    [[0, 1], [2, 3], [8, 9]]
    """
    m, r, c = mosaic.grid, mosaic.rows, mosaic.columns
    tiles = arr.reshape(m, r, m, c).transpose(0, 2, 1, 3).reshape(m * m, r, c)
    return tiles[: mosaic.slices]
