"""Raw binary volume files: headerless, x fastest, the shape and type in the name
(``tooth_103x94x161_uint8.raw``) or given; memory-mapped reads checked against the file's size,
and bounded writes. The NRRD reader (:mod:`hevr.volume.nrrd`) maps its raw data with
:func:`read_raw` and writes with :func:`data_parts`; the loaders (:mod:`hevr.volume.loaders`)
check a path with :func:`check_file`.
"""

from __future__ import annotations

import gzip
import io
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import check_regular, write_file
from ..core.validate import check_shape
from ..core.voxels import check_dtype
from ..errors import MissingFileError, ParameterError
from .nrrd_encodings import _fail

__all__ = [
    "RAW_DTYPES",
    "check_file",
    "data_parts",
    "is_kind",
    "load_raw",
    "raw_layout",
    "read_raw",
    "to_native",
    "write_raw",
]

# Type tokens recognised in raw file names like "tooth_103x94x161_uint8.raw".
RAW_DTYPES = ("int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64")
_RAW_SHAPE = re.compile(r"(?<![0-9])([0-9]+)x([0-9]+)x([0-9]+)(?![0-9])")
_RAW_DTYPE = re.compile(r"(?<![a-z0-9])(" + "|".join(RAW_DTYPES) + r")(?![a-z0-9])")


def is_kind(path: Path, directory: bool = False) -> bool:
    """``path.is_dir()`` / ``path.is_file()``, but False (not an error) for names the OS
    refuses (too long, a NUL byte)."""
    try:
        return path.is_dir() if directory else path.is_file()
    except (OSError, ValueError):
        return False


def check_file(path: Path) -> Path:
    """Return ``path`` if it is an existing regular file, else raise :class:`hevr.MissingFileError`
    (nothing there) or :class:`hevr.NotRegularFileError` (a FIFO, a socket, a device, a folder:
    reading one would block or fail)."""
    if not is_kind(path):
        try:
            there = path.exists()
        except (OSError, ValueError):  # a name the OS refuses names nothing
            there = False
        if there:
            check_regular(path, "path", "a volume file")
        raise MissingFileError("path", "a volume file", path)
    return path


def to_native(arr: np.ndarray) -> np.ndarray:
    """Native-byte-order version of ``arr`` (a view when it already is native)."""
    if arr.dtype.isnative:
        # '<i2' on a little-endian machine: same bytes, but show it as plain 'int16'.
        return arr if arr.dtype.byteorder in "=|" else arr.view(arr.dtype.newbyteorder("="))
    # astype reads the (possibly memory-mapped) data once and swaps it in the copy.
    return arr.astype(arr.dtype.newbyteorder("="))


def read_raw(
    path: Path, offset: int, shape: tuple[int, ...], dtype: np.dtype, *, exact: bool = True, what: str = ""
) -> np.ndarray:
    """Memory-map ``prod(shape)`` values of ``dtype`` at ``offset`` of ``path``, read-only.

    ``exact`` demands that the data end exactly at the end of the file: a size mismatch
    almost always means wrong sizes or type, which would otherwise give silent garbage.
    """
    need = math.prod(shape) * dtype.itemsize
    have = path.stat().st_size - offset
    where = f" after {offset} header/skip bytes" if offset else ""
    if have < need:
        raise _fail(
            path,
            f"truncated: {what}expected {need} bytes of data{where} "
            f"(shape {shape} of {dtype.name}), the file holds {max(have, 0)}",
            corrupt=True,
        )
    if exact and have != need:
        raise _fail(
            path,
            f"size mismatch: {what}expected {need} bytes of data{where} "
            f"(shape {shape} of {dtype.name}), the file holds {have}",
        )
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="C")


def raw_layout(path: Path) -> tuple[tuple[int, int, int] | None, str | None]:
    """(shape in (z, y, x) order, dtype name) from a name like ``a_103x94x161_uint8.raw``."""
    stem = path.name[: -len(path.suffix)].lower()
    sizes, types = _RAW_SHAPE.findall(stem), _RAW_DTYPE.findall(stem)
    shape = tuple(int(s) for s in reversed(sizes[-1])) if sizes else None  # name is x*y*z
    return shape, (types[-1] if types else None)  # type: ignore[return-value]


def load_raw(path: Path, shape: object, dtype: object, byte_order: str) -> np.ndarray:
    """Memory-map a headerless ``.raw`` file; ``shape``/``dtype`` default to the name's tokens."""
    name_shape, name_dtype = raw_layout(path)
    if shape is not None:
        shape = check_shape(shape)
    else:
        shape = name_shape
        if shape is not None and min(shape) < 1:
            sizes = "x".join(str(v) for v in reversed(shape))
            raise _fail(
                path,
                f"shape: expected positive sizes in the name's XxYxZ token, got {sizes}; "
                "rename the file or pass shape=(nz, ny, nx)",
            )
    dt: np.dtype | None = None
    if dtype is not None:
        dt = check_dtype(dtype)
    elif name_dtype:
        dt = np.dtype(name_dtype)
    if shape is None or dt is None:
        missing = " and ".join(w for w, v in (("shape", shape), ("dtype", dt)) if v is None)
        raise _fail(
            path,
            f"cannot tell the {missing} of this raw file: name it like "
            f"'name_XxYxZ_uint8.raw' (sizes x, y, z; type one of "
            f"{', '.join(RAW_DTYPES)}) or pass shape=(nz, ny, nx) and dtype=",
        )
    return read_raw(path, 0, shape, dt.newbyteorder("<" if byte_order == "little" else ">"))


def write_raw(path: Path, vol: np.ndarray, byte_order: str = "little", *, overwrite: bool = False) -> None:
    """Write ``vol`` as headerless x-fastest data, refusing names that describe another layout
    (atomically; an existing file only with ``overwrite``: :func:`hevr.core.files.write_file`)."""
    name_shape, name_dtype = raw_layout(path)
    if name_shape not in (None, vol.shape) or name_dtype not in (None, vol.dtype.name):
        raise ParameterError(
            f"save_volume: the name {path.name} says shape {name_shape} (z, y, x) "
            f"of {name_dtype}, but vol has shape {vol.shape} of {vol.dtype}"
        )
    write_file(path, data_parts(vol, byte_order, "raw"), overwrite=overwrite, doing="writing the volume")


def data_parts(vol: np.ndarray, byte_order: str | None, encoding: str) -> Iterator[Any]:
    """``vol`` in x-fastest order as bytes-like parts, one z-slab of at most 16 MiB at a time (bounded
    memory), in ``byte_order`` ("little", "big"; None: ``vol``'s own), gzip-compressed with
    ``encoding="gzip"`` (mtime 0: the same volume always gives the same bytes)."""
    dt = vol.dtype if byte_order is None else vol.dtype.newbyteorder("<" if byte_order == "little" else ">")
    step = max(1, (1 << 24) // max(1, vol[0].nbytes))
    # memoryviews of the converted slabs: no second copy of the data
    slabs = (np.ascontiguousarray(vol[k : k + step], dtype=dt).data for k in range(0, vol.shape[0], step))
    if encoding != "gzip":
        yield from slabs
        return
    buf = io.BytesIO()
    with gzip.GzipFile(fileobj=buf, mode="wb", mtime=0) as out:
        for slab in slabs:
            out.write(slab)
            yield buf.getvalue()
            buf.seek(0)
            buf.truncate()
    yield buf.getvalue()
