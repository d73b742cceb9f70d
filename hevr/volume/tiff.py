"""Multi-page TIFF stacks (``.tif``, ``.tiff``, OME-TIFF, ImageJ hyperstacks), through tifffile.

A stack of greyscale pages is a volume of shape (pages, rows, columns) = (nz, ny, nx).
tifffile names the axes of the file's first series (its full resolution): ``Z``, or ``Q``/``I``
for a plain page sequence, then ``Y``, ``X``; ImageJ hyperstacks and OME-TIFF may add
``T`` (time), ``C`` (channels) and ``S`` (samples: RGB). hevr encrypts one scalar per voxel:

* axes of size 1 are dropped;
* ``T`` (more than one time point) needs ``volume=i``, as for a 4-D NIfTI file;
* ``C`` or ``S`` of more than one entry (RGB, multi-channel) is refused: convert to one
  channel first (``tifffile.imwrite(..., photometric="minisblack")`` writes greyscale
  pages; a 3-D array written without it may be taken for one planar RGB page).

Spacing, in the file's own unit (micrometres for most microscopes; ``details["unit"]``):
ImageJ files give ``spacing`` (z) in their description and ``XResolution``/``YResolution``
(pixels per unit) for x and y; OME-TIFF gives ``PhysicalSizeX/Y/Z`` (converted to the x
unit when the axes' units differ, :mod:`hevr.volume._units`; a size that is not a number is
refused); anything else is (1, 1, 1). TIFF records no patient orientation: ``frame`` is None, axes as stored.

Uncompressed contiguous data is memory-mapped (``tifffile.memmap``); compressed or
scattered pages are read into memory, after checking that their declared size fits in it.
"""

from __future__ import annotations

import logging
import math
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HevrError, VolumeFormatError
from ._memory import check_fits
from ._optional import require
from ._select import reject_index, select_index
from ._units import common_unit
from .scan import Scan

__all__ = ["read_tiff"]

_log = logging.getLogger(__name__)

_DEPTH = "ZQI"  # axes tifffile uses for a stack of pages


def _ratio(page: Any, tag: str) -> float:
    """Units per pixel from a resolution tag (pixels per unit); 1 when absent."""
    value = page.tags[tag].value if tag in page.tags else (1, 1)
    num, den = value if isinstance(value, tuple) else (value, 1)
    return float(den) / float(num) if num else math.inf


def _number(path: Path, field: str, value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise VolumeFormatError(f"{path.name}: {field}: expected a number, got {str(value)[:40]!r}") from None


def _ome_spacing(path: Path, xml: str) -> tuple[tuple[float, float, float], str | None] | None:
    """PhysicalSizeX/Y/Z of the first OME image (missing ones are 1) in one unit, and that unit."""
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError:
        return None
    pixels = next((el for el in root.iter() if el.tag.rsplit("}", 1)[-1] == "Pixels"), None)
    if pixels is None:
        return None
    sizes = [_number(path, f"OME PhysicalSize{a}", pixels.get(f"PhysicalSize{a}", "1")) for a in "XYZ"]
    # The OME schema's default unit is the micrometre; a z step in mm is converted.
    return common_unit(path.name, sizes, [pixels.get(f"PhysicalSize{a}Unit", "µm") for a in "XYZ"])


def _spacing(path: Path, tif: Any) -> tuple[tuple[float, float, float], str | None]:
    page = tif.pages[0]
    if tif.is_imagej and tif.imagej_metadata is not None:
        meta = tif.imagej_metadata
        return (
            _ratio(page, "XResolution"),
            _ratio(page, "YResolution"),
            _number(path, "ImageJ spacing", meta.get("spacing", 1.0)),
        ), meta.get("unit")
    if tif.is_ome and tif.ome_metadata:
        found = _ome_spacing(path, tif.ome_metadata)
        if found is not None:
            return found
    return (1.0, 1.0, 1.0), None


def _index(path: Path, axes: str, shape: tuple, volume: int | None) -> tuple[tuple, dict[str, Any]]:
    """What to take along each of the series' axes so that (Z, Y, X) remain."""
    index: list[Any] = []
    details: dict[str, Any] = {"axes": axes}
    kept = ""
    for ax, size in zip(axes, shape):
        if ax in "CS" and size > 1:
            raise VolumeFormatError(
                f"{path.name}: expected greyscale pages, got {size} {'channels' if ax == 'C' else 'samples per pixel'} "
                f"(axes {axes}, shape {shape}); hevr encrypts one scalar per voxel: convert to one channel first"
            )
        if ax == "T" and size > 1:
            picked = select_index(volume, size, path, "time points", "its T axis")
            index.append(picked)
            details.update(volume=picked, volumes=size)
        elif size == 1 and ax not in "YX":
            index.append(0)
        elif ax in "YX" or ax in _DEPTH:
            index.append(slice(None))
            kept += "Z" if ax in _DEPTH else ax
        else:
            raise VolumeFormatError(
                f"{path.name}: unexpected TIFF axis {ax!r} of size {size} (axes {axes}, "
                f"shape {shape}); expected pages (Z) of Y x X pixels"
            )
    if "volume" not in details:
        reject_index(volume, path)
    if kept != "ZYX":
        raise VolumeFormatError(
            f"{path.name}: expected a 3-D stack of pages (Z, Y, X), got axes {axes} of shape {shape}"
        )
    return tuple(index), details


def read_tiff(path: Path, *, volume: int | None = None) -> Scan:
    """Read a TIFF stack into a :class:`Scan` (axes as stored, ``frame=None``)."""
    tifffile = require("tifffile", path)
    try:
        with tifffile.TiffFile(str(path)) as tif:
            series = tif.series[0]
            axes, shape, dtype = series.axes, tuple(series.shape), np.dtype(series.dtype)
            index, details = _index(path, axes, shape, volume)
            if dtype.kind not in "iuf":
                raise VolumeFormatError(f"{path.name}: expected integer or floating-point pixels, got {dtype}")
            spacing, details["unit"] = _spacing(path, tif)
            if len(tif.series) > 1:
                _log.info("%s: holds %d image series; reading the first", path.name, len(tif.series))
            # Uncompressed contiguous data is mapped (picking a view); anything else is read whole.
            mappable = series.dataoffset is not None
            if not mappable:
                check_fits(path.name, shape, dtype, "compressed or scattered TIFF data")
            read = None if mappable else series.asarray()
        data = tifffile.memmap(str(path), mode="r", series=0) if read is None else read
    except HevrError:
        raise
    except Exception as exc:  # tifffile raises many types for broken files
        raise VolumeFormatError(f"{path.name}: cannot read TIFF file ({exc})") from None
    return Scan(data[index], spacing, (0.0, 0.0, 0.0), None, None, str(path), details)
