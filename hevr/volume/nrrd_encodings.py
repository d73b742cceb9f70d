"""NRRD data encodings other than ``raw``: ``gzip``, ``bzip2``, ``hex`` and ``ascii``.

hevr decodes gzip, bzip2 and hex itself, block by block, and stops one byte after the size
the header announces: a "zip bomb" costs at most that size, and data that does not fit
this machine's memory is refused before anything is read (compressed and text data cannot
be memory-mapped; raw NRRD can). ``byte skip`` applies to the decompressed stream
(format.html, "byte skip") and may pass at most the data's size + :data:`MAX_GZIP_SKIP`.
``ascii`` (``text``, ``txt``) data, whitespace-separated numbers, is parsed by pynrrd (the
``hevr[io]`` extra); hevr hands it only the data, with the header it has checked itself.
"""

from __future__ import annotations

import bz2
import gzip
import math
import warnings
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CorruptVolumeError, VolumeFormatError
from . import _memory
from ._optional import require

__all__ = ["ENCODINGS", "MAX_GZIP_SKIP", "BLOCK", "read_compressed", "read_hex", "read_ascii"]

#: Every spelling of the NRRD "encoding" field, mapped to the reader's name.
ENCODINGS = {
    "raw": "raw",
    "gzip": "gzip",
    "gz": "gzip",
    "bzip2": "bzip2",
    "bz2": "bzip2",
    "hex": "hex",
    "ascii": "ascii",
    "text": "ascii",
    "txt": "ascii",
}
BLOCK = 1 << 20  # read compressed data, text and skipped lines in blocks of this many bytes
_OPENERS: dict[str, Any] = {"gzip": lambda fh: gzip.GzipFile(fileobj=fh, mode="rb"), "bzip2": bz2.BZ2File}


def _fail(path: Path, problem: str, *, corrupt: bool = False) -> VolumeFormatError:
    """The error naming ``path``; ``corrupt``: its data is damaged (:class:`CorruptVolumeError`)."""
    return (CorruptVolumeError if corrupt else VolumeFormatError)(f"{path.name}: {problem}")


MAX_GZIP_SKIP = 64 << 20  # bytes of decompressed stream a compressed "byte skip" may pass beyond the data's size


def _check_memory(path: Path, need: int, shape: tuple[int, ...], dtype: np.dtype, what: str, encoding: str) -> None:
    memory = _memory.physical_memory()
    if memory is not None and need > memory:  # compressed and text data are decoded into memory
        raise _fail(
            path,
            f"too big: {what}{need} bytes of {encoding} data (shape {shape} of "
            f"{dtype.name}), more than this machine's {memory} bytes of memory; "
            "store it with raw encoding, which is memory-mapped",
        )


def _decoded(
    path: Path, data: bytes | bytearray, need: int, shape: tuple[int, ...], dtype: np.dtype, what: str, encoding: str
) -> np.ndarray:
    if len(data) != need:
        raise _fail(
            path,
            f"{'truncated' if len(data) < need else 'size mismatch'}: {what}"
            f"expected {need} bytes of decoded {encoding} data (shape {shape} of "
            f"{dtype.name}), got {len(data) if len(data) < need else f'more than {need}'}",
            corrupt=len(data) < need,
        )
    return np.frombuffer(memoryview(data), dtype=dtype).reshape(shape)


def read_compressed(
    path: Path, offset: int, byte_skip: int, shape: tuple[int, ...], dtype: np.dtype, what: str, encoding: str
) -> np.ndarray:
    need = math.prod(shape) * dtype.itemsize
    if byte_skip > need + MAX_GZIP_SKIP:  # skipping means decompressing: seconds per GB
        raise _fail(
            path,
            f"NRRD 'byte skip': expected at most {need + MAX_GZIP_SKIP} bytes before "
            f"{what}{encoding} data of {need} bytes, got {byte_skip}",
        )
    _check_memory(path, need, shape, dtype, what, encoding)
    buf = bytearray()
    with open(path, "rb") as fh:
        fh.seek(offset)
        try:
            # GzipFile/BZ2File handle concatenated members; byte skip applies to the
            # decompressed stream (format.html, "byte skip"). Decompress no more than
            # byte skip + the announced size + 1 byte (to tell "too much"), in blocks.
            with _OPENERS[encoding](fh) as stream:
                skipped = 0
                while skipped < byte_skip:
                    block = stream.read(min(BLOCK, byte_skip - skipped))
                    if not block:
                        break
                    skipped += len(block)
                while len(buf) <= need:
                    block = stream.read(min(BLOCK, need + 1 - len(buf)))
                    if not block:
                        break
                    buf += block
        except (OSError, EOFError, ValueError, zlib.error) as exc:
            raise _fail(path, f"corrupt or truncated {encoding} data: {exc}", corrupt=True) from None
    return _decoded(path, buf, need, shape, dtype, what, encoding)


def read_hex(path: Path, offset: int, shape: tuple[int, ...], dtype: np.dtype, what: str) -> np.ndarray:
    """Two hexadecimal digits per byte, whitespace ignored; read in blocks up to the announced size."""
    need = math.prod(shape) * dtype.itemsize
    _check_memory(path, need, shape, dtype, what, "hex")
    buf, carry = bytearray(), b""
    with open(path, "rb") as fh:
        fh.seek(offset)
        while len(buf) <= need:
            block = fh.read(BLOCK)
            if not block:
                break
            digits = carry + block.translate(None, b" \t\r\n\v\f")
            cut = len(digits) - len(digits) % 2
            try:
                buf += bytes.fromhex(digits[:cut].decode("ascii"))
            except (UnicodeDecodeError, ValueError):
                raise _fail(
                    path, f"hex data: expected hexadecimal digits and whitespace, got {digits[:cut][:20]!r}..."
                ) from None
            carry = digits[cut:]
    if carry and len(buf) < need:
        raise _fail(path, f"hex data: an odd number of hexadecimal digits ({what}{need} bytes)")
    return _decoded(path, buf, need, shape, dtype, what, "hex")


def read_ascii(
    path: Path, data_path: Path, offset: int, shape: tuple[int, ...], dtype: np.dtype, type_name: str, what: str
) -> np.ndarray:
    """Whitespace-separated numbers, parsed by pynrrd (the ``hevr[io]`` extra); ``type_name`` in NRRD words."""
    nrrd = require("nrrd", path)
    need = math.prod(shape)
    _check_memory(path, need * dtype.itemsize, shape, dtype, what, "ascii")
    # Only the data is handed over: hevr has checked the header and found the data's start.
    header = {"dimension": len(shape), "type": type_name, "encoding": "ascii", "sizes": np.array(shape[::-1])}
    try:
        with open(data_path, "rb") as fh:
            fh.seek(offset)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)  # numpy: "could not be read to its end"
                data = nrrd.read_data(header, fh, None, index_order="C")
    except (nrrd.NRRDError, ValueError, OSError) as exc:
        raise _fail(
            path, f"ascii data in {data_path.name}: {what}{need} numbers (shape {shape} of {dtype.name}): {exc}"
        ) from None
    return np.asarray(data, dtype=dtype).reshape(shape)
