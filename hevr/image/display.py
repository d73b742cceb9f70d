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

from ..core.files import write_file
from ..core.validate import check_bool
from ..errors import ParameterError
from .orient import DEFAULT_CONVENTION, orient_slice

__all__ = ["default_window", "save_png", "to_uint8"]


def default_window(arr: np.ndarray, hits: np.ndarray | None = None) -> tuple[float, float]:
    """The window :func:`to_uint8` uses when none is given.

    Images without negative values (MRI, the phantom, colours): ``0`` .. the 99.9th percentile
    of the positive values, so that a dark background stays black. A grey image with negative
    values (a CT X-ray in Hounsfield units, background near -1000): its value range, the 0.1th ..
    99.9th percentile, so that the object is brighter than the air around it (0 .. p99.9 would
    turn everything below 0 black). ``hits`` (an image's mask of pixels with a value) leaves
    the pixels without one out of the statistics.

    Examples
    --------
    >>> default_window(np.array([[0.0, 2.0], [4.0, 8.0]]))
    (0.0, 7.992)
    >>> default_window(np.array([[-1000.0, -1000.0], [-500.0, 30.0]]))
    (-1000.0, 28.41)
    """
    a = np.asarray(arr, dtype=np.float64)
    vals = a[np.asarray(hits, dtype=bool)] if hits is not None and a.ndim == 2 else a
    vals = vals[np.isfinite(vals)]
    if a.ndim == 2 and vals.size and float(vals.min()) < 0:
        lo, hi = (float(x) for x in np.percentile(vals, [0.1, 99.9]))
        return round(lo, 12), round(hi, 12)
    pos = vals[vals > 0]
    return 0.0, round(float(np.percentile(pos, 99.9)), 12) if pos.size else 1.0


def to_uint8(arr: np.ndarray, window: tuple[float, float] | None = None, hits: np.ndarray | None = None) -> np.ndarray:
    """Window an image to uint8: grey by (lo, hi) (default: :func:`default_window` — 0 .. the
    99.9th percentile of positive pixels, or the value range of an image with negative values);
    RGB jointly over all channels so colours keep their ratios. Pixels outside ``hits`` (rays
    that missed the volume) are black."""
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise ParameterError(f"arr: expected shape (H, W) or (H, W, 3), got {a.shape}")
    if hits is not None and np.shape(hits) != a.shape[:2]:
        raise ParameterError(f"hits: expected a mask of shape {a.shape[:2]}, got {np.shape(hits)}")
    lo, hi = default_window(a, hits) if window is None else (float(window[0]), float(window[1]))
    if not hi > lo:
        hi = lo + 1.0
    out = (np.clip((a - lo) / (hi - lo), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if hits is not None:
        out[~np.asarray(hits, dtype=bool)] = 0
    return out


def save_png(
    arr: np.ndarray,
    path: str | Path,
    window: tuple[float, float] | None = None,
    *,
    overwrite: bool = False,
    plane: Any = None,
    convention: str = DEFAULT_CONVENTION,
    hits: np.ndarray | None = None,
) -> None:
    """Save a decrypted (or plaintext) image as PNG with sensible windowing (:func:`default_window`;
    ``hits``: the pixels with a value, the others black and left out of the window).

    Given the ``plane`` of a slice (a :class:`hevr.Plane` or its ``to_dict()``), the slice is
    written the way radiology viewers show it (:func:`hevr.image.orient.orient_slice`:
    radiological by default — an axial slice with anterior at the top and the patient's right on
    the left, coronal and sagittal ones with superior at the top), not in the raw array order.

    Encoded in memory, then written atomically (:func:`hevr.core.files.write_file`): never over an
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
    img = to_uint8(arr, window, hits)
    if plane is not None:
        img = orient_slice(img, plane, convention)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img)).save(buf, format="PNG")
    write_file(path, [buf.getbuffer()], overwrite=overwrite, doing="writing the PNG")
