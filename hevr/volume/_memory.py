"""Refuse to decode more than this machine's memory: the readers' guard against huge declared sizes.

Compressed data (``.nii.gz``, compressed TIFF pages, Zarr chunks, encapsulated DICOM pixel
data) cannot be memory-mapped: its reader allocates the whole declared array before it
finds out that the file holds a few bytes. A header that announces terabytes would then
exhaust the machine (or be killed by the OS) instead of being refused. Every such reader
first compares the declared size with the physical memory and refuses larger ones with a
:class:`hevr.VolumeFormatError` naming the file, before anything is allocated.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from ..errors import VolumeFormatError

__all__ = ["check_fits", "physical_memory"]


def physical_memory() -> int | None:
    """Bytes of RAM of this machine, or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def check_fits(name: str, shape: Any, dtype: Any, what: str) -> None:
    """Refuse decoding ``shape`` voxels of ``dtype`` into memory when that exceeds the RAM.

    >>> check_fits("a.nii.gz", (2, 3, 4), np.int16, "compressed NIfTI data")
    >>> check_fits("a.nii.gz", (10**9,) * 3, np.int16, "compressed data")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hevr.errors.VolumeFormatError: a.nii.gz: too big: 2000000000000000000000000000 bytes of compressed data ...
    """
    dt = np.dtype(dtype)
    need = math.prod(int(s) for s in shape) * dt.itemsize
    memory = physical_memory()
    if memory is not None and need > memory:
        raise VolumeFormatError(
            f"{name}: too big: {need} bytes of {what} (shape {tuple(int(s) for s in shape)} "
            f"of {dt.name}) declared, more than this machine's {memory} bytes of memory"
        )
