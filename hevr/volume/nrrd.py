"""NRRD volume files: hevr's own header parser and raw/gzip/bzip2/hex reader (headerless raw
files, and the memory map under NRRD's raw data, are in :mod:`hevr.volume.raw`).

Implements the part of the NRRD format (http://teem.sourceforge.net/nrrd/format.html)
that scalar volumes need: attached (``.nrrd``) and detached (``.nhdr``) headers, a
single data file, 3-D and 4-D ``sizes``, ``type``/``endian``, ``line skip``/``byte skip``
and the encodings ``raw``, ``gzip``, ``bzip2``, ``hex`` and ``ascii`` (the last through
pynrrd; see :mod:`hevr.volume.nrrd_encodings`). :func:`read_nrrd` returns the data and the
header fields; :mod:`hevr.volume.nrrd_space` turns ``space``/``space directions``/
``space origin``/``kinds`` into hevr's patient frame and picks one volume of a 4-D file.

Raw uncompressed data is memory-mapped so huge volumes are read only once, when used.

Hostile files end in :class:`hevr.VolumeFormatError` (or :class:`hevr.MissingFileError`),
quickly and in bounded memory: sizes are checked against the file before anything is
mapped, compressed data is decompressed only up to the size the header announces (a "zip
bomb" costs at most that), a compressed ``byte skip`` may pass at most the data's size +
64 MiB (it is decompressed to be skipped), ``line skip`` stops at the end of the file, and
header numbers must be ASCII decimal integers.
"""

from __future__ import annotations

import itertools
import logging
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import write_file
from ..errors import ExistingFileError, ParameterError
from .nrrd_encodings import (
    BLOCK,
    ENCODINGS,
    _fail,
    read_ascii,
    read_compressed,
    read_hex,
)
from .raw import check_file, data_parts, read_raw

_log = logging.getLogger(__name__)

# Every spelling of the NRRD "type" field (format.html, "type"), mapped to numpy.
_TYPES: dict[str, str] = {}
for _names, _np in (
    ("signed char|int8|int8_t", "i1"),
    ("uchar|unsigned char|uint8|uint8_t", "u1"),
    ("short|short int|signed short|signed short int|int16|int16_t", "i2"),
    ("ushort|unsigned short|unsigned short int|uint16|uint16_t", "u2"),
    ("int|signed int|int32|int32_t", "i4"),
    ("uint|unsigned int|uint32|uint32_t", "u4"),
    ("longlong|long long|long long int|signed long long|signed long long int|int64|int64_t", "i8"),
    ("ulonglong|unsigned long long|unsigned long long int|uint64|uint64_t", "u8"),
    ("float", "f4"),
    ("double", "f8"),
):
    _TYPES.update(dict.fromkeys(_names.split("|"), _np))

# Canonical names written by ``write_nrrd`` (the stdint spellings teem itself prefers).
_TYPE_NAMES = {
    "i1": "int8",
    "u1": "uint8",
    "i2": "int16",
    "u2": "uint16",
    "i4": "int32",
    "u4": "uint32",
    "i8": "int64",
    "u8": "uint64",
    "f4": "float",
    "f8": "double",
}

_MAX_HEADER_BYTES = 1 << 20  # a header larger than this is certainly not a header
_INT = re.compile(r"[+-]?[0-9]+")  # int() alone would also take '٢', '1_0' and ' 1 '


def _read_header(path: Path) -> tuple[dict[str, str], int]:
    """Parse the header lines of ``path``; return the fields and the byte offset after them."""
    fields: dict[str, str] = {}
    with open(path, "rb") as fh:
        magic = fh.readline(64).rstrip(b"\r\n")
        if not re.fullmatch(rb"NRRD000[1-5]", magic):
            raise _fail(path, f"not an NRRD file: expected a first line 'NRRD0001'..'NRRD0005', got {magic[:20]!r}")
        while True:
            raw = fh.readline(_MAX_HEADER_BYTES)
            if fh.tell() > _MAX_HEADER_BYTES:
                raise _fail(
                    path, f"NRRD header is longer than {_MAX_HEADER_BYTES} bytes (missing blank line before the data?)"
                )
            line = raw.rstrip(b"\r\n").decode("latin-1")
            if not line:  # a blank line (or EOF for a detached header) ends the header
                return fields, fh.tell()
            if line.startswith("#") or ":=" in line.split(": ", 1)[0]:
                continue  # comments and key/value pairs carry nothing we need
            key, sep, value = line.partition(": ")
            if not sep:
                raise _fail(path, f"malformed NRRD header line {line[:80]!r}: expected 'field: value'")
            fields[key.strip().lower()] = value.strip()
            if key.strip().lower() in ("data file", "datafile") and value.upper().startswith("LIST"):
                return fields, fh.tell()  # file names follow; read_nrrd rejects the form


def _ints(path: Path, field: str, value: str, count: int) -> list[int]:
    words = value.split()
    try:
        out = [int(v) for v in words] if all(_INT.fullmatch(v) for v in words) else []
    except ValueError:  # more than 4300 digits
        out = []
    if len(out) != count:
        raise _fail(path, f"NRRD field '{field}' must hold {count} integer(s), got {value!r}")
    return out


def read_nrrd(
    path: Path, before_data: Callable[[dict[str, str], tuple[int, ...]], Any] | None = None
) -> tuple[np.ndarray, dict[str, str], Any]:
    """Read the data of a 3-D or 4-D ``.nrrd``/``.nhdr`` file.

    ``before_data(fields, shape)``, when given, runs once the header is checked and before
    any data is read (so geometry problems are refused without decompressing anything); what
    it returns is the third item of the result.

    Returns the array with the file's sizes reversed (slowest axis first, so a 3-D file
    comes as (z, y, x)), in the file's byte order (so that picking one volume of a 4-D
    big-endian file swaps only that one; :func:`to_native` later), and the header fields
    (lower-case names) for :mod:`hevr.volume.nrrd_space` to turn into geometry.
    """
    check_file(path)
    fields, header_end = _read_header(path)
    for required in ("type", "dimension", "sizes", "encoding"):
        if required not in fields:
            raise _fail(path, f"NRRD header lacks the required field '{required}'")

    type_name = " ".join(fields["type"].lower().split())
    if type_name not in _TYPES:
        raise _fail(
            path,
            f"NRRD type {fields['type']!r} is not supported: expected an integer "
            "or floating-point type (e.g. uint8, int16, float)",
        )
    dim = _ints(path, "dimension", fields["dimension"], 1)[0]
    if dim not in (3, 4):
        raise _fail(path, f"expected a 3-D volume (dimension: 3, or 4 with one non-spatial axis), got dimension: {dim}")
    sizes = _ints(path, "sizes", fields["sizes"], dim)
    if min(sizes) < 1:
        raise _fail(path, f"NRRD sizes must be positive, got {fields['sizes']!r}")
    shape = tuple(reversed(sizes))

    encoding = ENCODINGS.get(fields["encoding"].lower())
    if encoding is None:
        raise _fail(
            path, f"NRRD encoding {fields['encoding']!r} is not supported: expected raw, gzip, bzip2, ascii or hex"
        )
    dtype = np.dtype(_TYPES[type_name])
    endian = fields.get("endian", "").lower()
    if dtype.itemsize > 1 and encoding != "ascii":
        if endian not in ("little", "big"):
            raise _fail(
                path,
                f"NRRD field 'endian' must be 'little' or 'big' for type "
                f"{fields['type']}, got {fields.get('endian')!r}",
            )
        dtype = dtype.newbyteorder("<" if endian == "little" else ">")

    data_path, offset = path, header_end
    if "data file" in fields or "datafile" in fields:
        spec = fields.get("data file", fields.get("datafile", ""))
        parts = spec.split()
        # The multi-file forms are "LIST" and "<printf format> <min> <max> <step> [<subdim>]";
        # anything else is one file name (which may contain spaces).
        if spec.upper().startswith("LIST") or (len(parts) in (4, 5) and "%" in parts[0]):
            raise _fail(path, f"NRRD 'data file: {spec}' names several files; only a single data file is supported")
        data_path = check_file((path.parent / spec) if not Path(spec).is_absolute() else Path(spec))
        offset = 0

    line_skip = _ints(path, "line skip", fields.get("line skip", "0"), 1)[0]
    byte_skip = _ints(path, "byte skip", fields.get("byte skip", "0"), 1)[0]
    if line_skip < 0 or byte_skip < -1:
        raise _fail(path, f"NRRD 'line skip' must be >= 0 and 'byte skip' >= -1, got {line_skip} and {byte_skip}")
    if line_skip:
        offset = _skip_lines(data_path, offset, line_skip)
    if byte_skip == -1 and encoding != "raw":
        raise _fail(path, f"NRRD 'byte skip: -1' is only allowed with raw encoding, got {encoding}")

    checked = None if before_data is None else before_data(fields, shape)
    what = f"header {path.name} says "
    if encoding == "raw":
        if byte_skip == -1:  # "the data is at the very end of the file"
            offset = max(offset, data_path.stat().st_size - math.prod(shape) * dtype.itemsize)
        arr = read_raw(data_path, offset + max(byte_skip, 0), shape, dtype, what=what)
    elif encoding in ("gzip", "bzip2"):
        arr = read_compressed(data_path, offset, byte_skip, shape, dtype, what, encoding)
    elif encoding == "hex":
        arr = read_hex(data_path, offset + byte_skip, shape, dtype, what)
    else:
        arr = read_ascii(path, data_path, offset + byte_skip, shape, dtype, _TYPE_NAMES[dtype.str[1:]], what)
    return arr, fields, checked


def _skip_lines(path: Path, offset: int, count: int) -> int:
    """The offset after ``count`` lines from ``offset`` (or the file's end), in bounded memory."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        for _ in range(count):
            line = fh.readline(BLOCK)
            while line and not line.endswith(b"\n"):
                line = fh.readline(BLOCK)
            if not line:  # end of file: read_raw reports the missing data
                break
        return fh.tell()


def write_nrrd(
    path: Path,
    vol: np.ndarray,
    spacing: tuple[float, float, float],
    *,
    encoding: str = "raw",
    byte_order: str = "little",
    overwrite: bool = False,
) -> Path | None:
    """Write ``vol`` (z, y, x) as NRRD; detached (``.nhdr`` + data file) or attached (``.nrrd``).
    Each file is written atomically; existing files are replaced only with ``overwrite``.

    Returns the path of the detached data file, or ``None`` for an attached file.
    """
    type_name = _TYPE_NAMES.get(vol.dtype.str[1:])
    if type_name is None:
        raise ParameterError(
            f"save_volume: NRRD cannot store {vol.dtype} ({path.name}); expected an integer type, float32 or float64"
        )
    nz, ny, nx = vol.shape
    sx, sy, sz = (repr(float(s)) for s in spacing)
    lines = [
        "NRRD0004",
        "# written by hevr",
        f"type: {type_name}",
        "dimension: 3",
        f"sizes: {nx} {ny} {nz}",
        "space dimension: 3",
        f"space directions: ({sx},0,0) (0,{sy},0) (0,0,{sz})",
        "kinds: domain domain domain",
        f"endian: {byte_order}",
        f"encoding: {encoding}",
    ]
    data_path = None
    if path.suffix.lower() == ".nhdr":
        data_path = path.with_suffix(".raw.gz" if encoding == "gzip" else ".raw")
        lines.append(f"data file: {data_path.name}")
        if not overwrite and data_path.exists():  # neither file is written when one is there
            raise ExistingFileError("path", data_path)
        write_file(
            data_path, data_parts(vol, byte_order, encoding), overwrite=overwrite, doing="writing the volume data"
        )
        write_file(
            path, [("\n".join(lines) + "\n").encode("ascii")], overwrite=overwrite, doing="writing the volume header"
        )
        return data_path
    head = ("\n".join(lines) + "\n\n").encode("ascii")  # attached: a blank line separates header and data
    write_file(
        path,
        itertools.chain([head], data_parts(vol, byte_order, encoding)),
        overwrite=overwrite,
        doing="writing the volume",
    )
    return None
