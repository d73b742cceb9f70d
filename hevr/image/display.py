"""Showing a decrypted (or plaintext) image: :func:`to_uint8` windows it to 8 bits,
:func:`save_png` writes it as a PNG file.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from .._files import write_file
from .._validate import check_bool
from ..errors import ParameterError
from .orient import DEFAULT_CONVENTION, orient_slice

__all__ = ["save_png", "to_uint8"]


def to_uint8(arr: np.ndarray, window: tuple[float, float] | None = None) -> np.ndarray:
    """Window an image to uint8: grey by (lo, hi) (default 0 .. 99.9th percentile of
    positive pixels); RGB jointly over all channels so colours keep their ratios."""
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise ParameterError(f"arr: expected shape (H, W) or (H, W, 3), got {a.shape}")
    if window is None:
        pos = a[np.isfinite(a) & (a > 0)]
        hi = float(np.percentile(pos, 99.9)) if pos.size else 1.0
        lo = 0.0
    else:
        lo, hi = float(window[0]), float(window[1])
    if not hi > lo:
        hi = lo + 1.0
    return (np.clip((a - lo) / (hi - lo), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save_png(arr: np.ndarray, path: str | Path, window: tuple[float, float] | None = None, *,
             overwrite: bool = False, plane: Any = None, convention: str = DEFAULT_CONVENTION) -> None:
    """Save a decrypted (or plaintext) image as PNG with sensible windowing.

    Given the ``plane`` of a slice (a :class:`hevr.Plane` or its ``to_dict()``), the slice is
    written the way radiology viewers show it (:func:`hevr.image.orient.orient_slice`:
    radiological by default — an axial slice with anterior at the top and the patient's right on
    the left, coronal and sagittal ones with superior at the top), not in the raw array order.

    Encoded in memory, then written atomically (:func:`hevr._files.write_file`): never over an
    existing file unless ``overwrite=True`` (:class:`hevr.ExistingFileError`), and a failed
    write is a :class:`hevr.FileSystemError` that leaves nothing behind.

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> save_png(np.linspace(0, 1, 12).reshape(3, 4), os.path.join(tempfile.mkdtemp(), "a.png"))
    """

    overwrite = check_bool("overwrite", overwrite)
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ParameterError(f"path: expected a file path, got {path!r}")
    if plane is not None:
        arr = orient_slice(arr, plane, convention)
    buf = io.BytesIO()
    Image.fromarray(to_uint8(arr, window)).save(buf, format="PNG")
    write_file(path, [buf.getbuffer()], overwrite=overwrite, doing="writing the PNG")
