"""Raw binary and NRRD volume files, without any third-party NRRD library.

Implements the subset of the NRRD format (http://teem.sourceforge.net/nrrd/format.html)
that scalar 3-D volumes need: attached (``.nrrd``) and detached (``.nhdr``) headers, a
single data file, ``raw`` and ``gzip`` encodings, ``sizes``/``type``/``endian``, spacing
from ``space directions`` or ``spacings``, and ``line skip``/``byte skip``.

Raw uncompressed data is memory-mapped so huge volumes are read only once, when used.

Hostile files end in :class:`hevr.VolumeFormatError` (or :class:`hevr.MissingFileError`),
quickly and in bounded memory: sizes are checked against the file before anything is
mapped, gzip data is decompressed only up to the size the header announces (a "zip bomb"
costs at most that), a gzip ``byte skip`` may pass at most the data's size + 64 MiB (it
is decompressed to be skipped), ``line skip`` stops at the end of the file, and header numbers
must be ASCII decimal integers.
"""

from __future__ import annotations

import gzip
import logging
import math
import os
import re
import zlib
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .._validate import check_dtype, check_shape
from ..errors import MissingFileError, ParameterError, VolumeFormatError

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
_TYPE_NAMES = {"i1": "int8", "u1": "uint8", "i2": "int16", "u2": "uint16", "i4": "int32",
               "u4": "uint32", "i8": "int64", "u8": "uint64", "f4": "float", "f8": "double"}

# Type tokens recognised in raw file names like "tooth_103x94x161_uint8.raw".
RAW_DTYPES = ("int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64")
_RAW_SHAPE = re.compile(r"(?<![0-9])([0-9]+)x([0-9]+)x([0-9]+)(?![0-9])")
_RAW_DTYPE = re.compile(r"(?<![a-z0-9])(" + "|".join(RAW_DTYPES) + r")(?![a-z0-9])")
# Axis kinds of a scalar volume; others (RGB-color, vector, ...) mean a non-scalar axis.
_SCALAR_KINDS = {"domain", "space", "time", "none", "???"}

_MAX_HEADER_BYTES = 1 << 20  # a header larger than this is certainly not a header
_BLOCK = 1 << 20  # read gzip data and skipped lines in blocks of this many bytes
_INT = re.compile(r"[+-]?[0-9]+")  # int() alone would also take '٢', '1_0' and ' 1 '
_VECTOR = re.compile(r"\(([^()]*)\)")


def _fail(path: Path, problem: str) -> VolumeFormatError:
    return VolumeFormatError(f"{path.name}: {problem}")


def is_kind(path: Path, directory: bool = False) -> bool:
    """``path.is_dir()`` / ``path.is_file()``, but False (not an error) for names the OS
    refuses (too long, a NUL byte)."""
    try:
        return path.is_dir() if directory else path.is_file()
    except (OSError, ValueError):
        return False


def check_file(path: Path) -> Path:
    """Return ``path`` if it is an existing file, else raise :class:`hevr.MissingFileError`."""
    if not is_kind(path):
        raise MissingFileError("path", "a volume file", path)
    return path


def to_native(arr: np.ndarray) -> np.ndarray:
    """Native-byte-order version of ``arr`` (a view when it already is native)."""
    if arr.dtype.isnative:
        # '<i2' on a little-endian machine: same bytes, but show it as plain 'int16'.
        return arr if arr.dtype.byteorder in "=|" else arr.view(arr.dtype.newbyteorder("="))
    # astype reads the (possibly memory-mapped) data once and swaps it in the copy.
    return arr.astype(arr.dtype.newbyteorder("="))


def read_raw(path: Path, offset: int, shape: tuple[int, int, int], dtype: np.dtype,
             *, exact: bool = True, what: str = "") -> np.ndarray:
    """Memory-map ``prod(shape)`` values of ``dtype`` at ``offset`` of ``path``, read-only.

    ``exact`` demands that the data end exactly at the end of the file: a size mismatch
    almost always means wrong sizes or type, which would otherwise give silent garbage.
    """
    need = math.prod(shape) * dtype.itemsize
    have = path.stat().st_size - offset
    where = f" after {offset} header/skip bytes" if offset else ""
    if have < need:
        raise _fail(path, f"truncated: {what}expected {need} bytes of data{where} "
                          f"(shape {shape} of {dtype.name}), the file holds {max(have, 0)}")
    if exact and have != need:
        raise _fail(path, f"size mismatch: {what}expected {need} bytes of data{where} "
                          f"(shape {shape} of {dtype.name}), the file holds {have}")
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
            raise _fail(path, f"shape: expected positive sizes in the name's XxYxZ token, got {sizes}; "
                              "rename the file or pass shape=(nz, ny, nx)")
    dt: np.dtype | None = None
    if dtype is not None:
        dt = check_dtype(dtype)
    elif name_dtype:
        dt = np.dtype(name_dtype)
    if shape is None or dt is None:
        missing = " and ".join(w for w, v in (("shape", shape), ("dtype", dt)) if v is None)
        raise _fail(path, f"cannot tell the {missing} of this raw file: name it like "
                          f"'name_XxYxZ_uint8.raw' (sizes x, y, z; type one of "
                          f"{', '.join(RAW_DTYPES)}) or pass shape=(nz, ny, nx) and dtype=")
    return read_raw(path, 0, shape, dt.newbyteorder("<" if byte_order == "little" else ">"))


def write_raw(path: Path, vol: np.ndarray, byte_order: str = "little") -> None:
    """Write ``vol`` as headerless x-fastest data, refusing names that describe another layout."""
    name_shape, name_dtype = raw_layout(path)
    if name_shape not in (None, vol.shape) or name_dtype not in (None, vol.dtype.name):
        raise ParameterError(f"save_volume: the name {path.name} says shape {name_shape} (z, y, x) "
                             f"of {name_dtype}, but vol has shape {vol.shape} of {vol.dtype}")
    with open(path, "wb") as fh:
        _write_data(fh, vol, byte_order, "raw")


def _write_data(fh: BinaryIO, vol: np.ndarray, byte_order: str, encoding: str) -> None:
    """Stream ``vol`` in x-fastest order, converting one z-slab at a time (bounded memory)."""
    dt = vol.dtype.newbyteorder("<" if byte_order == "little" else ">")
    # mtime=0: the same volume always gives the same bytes.
    out = gzip.GzipFile(fileobj=fh, mode="wb", mtime=0) if encoding == "gzip" else fh
    try:
        step = max(1, (1 << 24) // max(1, vol[0].nbytes))
        for k in range(0, vol.shape[0], step):
            out.write(np.ascontiguousarray(vol[k : k + step], dtype=dt).data)
    finally:
        if out is not fh:
            out.close()


def _read_header(path: Path) -> tuple[dict[str, str], int]:
    """Parse the header lines of ``path``; return the fields and the byte offset after them."""
    fields: dict[str, str] = {}
    with open(path, "rb") as fh:
        magic = fh.readline(64).rstrip(b"\r\n")
        if not re.fullmatch(rb"NRRD000[1-5]", magic):
            raise _fail(path, f"not an NRRD file: expected a first line 'NRRD0001'..'NRRD0005', "
                              f"got {magic[:20]!r}")
        while True:
            raw = fh.readline(_MAX_HEADER_BYTES)
            if fh.tell() > _MAX_HEADER_BYTES:
                raise _fail(path, f"NRRD header is longer than {_MAX_HEADER_BYTES} bytes "
                                  "(missing blank line before the data?)")
            line = raw.rstrip(b"\r\n").decode("latin-1")
            if not line:  # a blank line (or EOF for a detached header) ends the header
                return fields, fh.tell()
            if line.startswith("#") or ":=" in line.split(": ", 1)[0]:
                continue  # comments and key/value pairs carry nothing we need
            key, sep, value = line.partition(": ")
            if not sep:
                raise _fail(path, f"malformed NRRD header line {line[:80]!r}: "
                                  "expected 'field: value'")
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


def _spacing(path: Path, fields: dict[str, str]) -> tuple[float, float, float]:
    """World spacing (sx, sy, sz) from 'space directions' (vector norms) or 'spacings'."""
    if "space directions" in fields:
        value = fields["space directions"]
        vectors = _VECTOR.findall(value)
        if len(vectors) != 3 or "none" in value.lower():
            raise _fail(path, "NRRD field 'space directions' must hold three vectors like "
                              f"'(1,0,0) (0,1,0) (0,0,1)' for the three axes, got {value!r}")
        try:
            vecs = [[float(c) for c in vec.split(",")] for vec in vectors]
        except ValueError:
            raise _fail(path, f"NRRD field 'space directions' has a non-numeric vector: {value!r}") from None
        out = [math.hypot(*v) for v in vecs]
        # hevr's world axes are the voxel axes, so only the lengths matter; say so when
        # the file also carries a rotation that is being dropped.
        if any(len(v) != 3 or abs(v[i]) < out[i] * (1 - 1e-9) for i, v in enumerate(vecs)):
            _log.info("%s: non-axis-aligned space directions %s; only their lengths %s are used",
                      path.name, value, out)
    elif "spacings" in fields:
        try:
            # NaN means "unknown" in NRRD: fall back to 1 like teem's tools do.
            out = [1.0 if math.isnan(float(v)) else float(v) for v in fields["spacings"].split()]
        except ValueError:
            out = []
        if len(out) != 3:
            raise _fail(path, f"NRRD field 'spacings' must hold 3 numbers, got {fields['spacings']!r}")
    else:
        out = [1.0, 1.0, 1.0]
    if not all(math.isfinite(v) and v > 0 for v in out):
        raise _fail(path, f"NRRD spacing must be three positive finite numbers, got {tuple(out)}")
    return out[0], out[1], out[2]


def read_nrrd(path: Path) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Read a 3-D ``.nrrd``/``.nhdr`` file: (array in (z, y, x) order, spacing (sx, sy, sz))."""
    check_file(path)
    fields, header_end = _read_header(path)
    for required in ("type", "dimension", "sizes", "encoding"):
        if required not in fields:
            raise _fail(path, f"NRRD header lacks the required field '{required}'")

    type_name = " ".join(fields["type"].lower().split())
    if type_name not in _TYPES:
        raise _fail(path, f"NRRD type {fields['type']!r} is not supported: expected an integer "
                          "or floating-point type (e.g. uint8, int16, float)")
    dim = _ints(path, "dimension", fields["dimension"], 1)[0]
    if dim != 3:
        raise _fail(path, f"expected a 3-D volume (dimension: 3), got dimension: {dim}")
    nx, ny, nz = _ints(path, "sizes", fields["sizes"], 3)
    if min(nx, ny, nz) < 1:
        raise _fail(path, f"NRRD sizes must be positive, got {fields['sizes']!r}")
    shape = (nz, ny, nx)
    kinds = fields.get("kinds", "").lower().split()
    if any(k not in _SCALAR_KINDS for k in kinds):
        raise _fail(path, f"expected a scalar 3-D volume, got axis kinds {fields['kinds']!r} "
                          "(a vector or colour axis)")

    dtype = np.dtype(_TYPES[type_name])
    endian = fields.get("endian", "").lower()
    if dtype.itemsize > 1:
        if endian not in ("little", "big"):
            raise _fail(path, f"NRRD field 'endian' must be 'little' or 'big' for type "
                              f"{fields['type']}, got {fields.get('endian')!r}")
        dtype = dtype.newbyteorder("<" if endian == "little" else ">")

    encoding = fields["encoding"].lower()
    if encoding not in ("raw", "gzip", "gz"):
        raise _fail(path, f"NRRD encoding {fields['encoding']!r} is not supported: "
                          "expected 'raw' or 'gzip'")

    data_path, offset = path, header_end
    if "data file" in fields or "datafile" in fields:
        spec = fields.get("data file", fields.get("datafile", ""))
        parts = spec.split()
        # The multi-file forms are "LIST" and "<printf format> <min> <max> <step> [<subdim>]";
        # anything else is one file name (which may contain spaces).
        if spec.upper().startswith("LIST") or (len(parts) in (4, 5) and "%" in parts[0]):
            raise _fail(path, f"NRRD 'data file: {spec}' names several files; only a "
                              "single data file is supported")
        data_path = check_file((path.parent / spec) if not Path(spec).is_absolute() else Path(spec))
        offset = 0

    line_skip = _ints(path, "line skip", fields.get("line skip", "0"), 1)[0]
    byte_skip = _ints(path, "byte skip", fields.get("byte skip", "0"), 1)[0]
    if line_skip < 0 or byte_skip < -1:
        raise _fail(path, f"NRRD 'line skip' must be >= 0 and 'byte skip' >= -1, "
                          f"got {line_skip} and {byte_skip}")
    if line_skip:
        offset = _skip_lines(data_path, offset, line_skip)

    spacing = _spacing(path, fields)
    what = f"header {path.name} says "
    if encoding == "raw":
        if byte_skip == -1:  # "the data is at the very end of the file"
            offset = max(offset, data_path.stat().st_size - math.prod(shape) * dtype.itemsize)
        arr = read_raw(data_path, offset + max(byte_skip, 0), shape, dtype, what=what)
    else:
        if byte_skip == -1:
            raise _fail(path, "NRRD 'byte skip: -1' is only allowed with raw encoding")
        arr = _read_gzip(data_path, offset, byte_skip, shape, dtype, what)
    return to_native(arr), spacing


def _skip_lines(path: Path, offset: int, count: int) -> int:
    """The offset after ``count`` lines from ``offset`` (or the file's end), in bounded memory."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        for _ in range(count):
            line = fh.readline(_BLOCK)
            while line and not line.endswith(b"\n"):
                line = fh.readline(_BLOCK)
            if not line:  # end of file: read_raw reports the missing data
                break
        return fh.tell()


def _physical_memory() -> int | None:
    """Bytes of RAM of this machine, or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


MAX_GZIP_SKIP = 64 << 20  # bytes of decompressed stream a gzip "byte skip" may pass beyond the data's size


def _read_gzip(path: Path, offset: int, byte_skip: int, shape: tuple[int, int, int],
               dtype: np.dtype, what: str) -> np.ndarray:
    need = math.prod(shape) * dtype.itemsize
    if byte_skip > need + MAX_GZIP_SKIP:  # skipping means decompressing: seconds per GB
        raise _fail(path, f"NRRD 'byte skip': expected at most {need + MAX_GZIP_SKIP} bytes before "
                          f"{what}gzip data of {need} bytes, got {byte_skip}")
    memory = _physical_memory()
    if memory is not None and need > memory:  # gzip data is decompressed into memory
        raise _fail(path, f"too big: {what}{need} bytes of gzip-compressed data (shape {shape} of "
                          f"{dtype.name}), more than this machine's {memory} bytes of memory; "
                          "store it with raw encoding, which is memory-mapped")
    buf = bytearray()
    with open(path, "rb") as fh:
        fh.seek(offset)
        try:
            # GzipFile handles concatenated members; byte skip applies to the
            # decompressed stream (format.html, "byte skip"). Decompress no more than
            # byte skip + the announced size + 1 byte (to tell "too much"), in blocks.
            with gzip.GzipFile(fileobj=fh, mode="rb") as gz:
                skipped = 0
                while skipped < byte_skip:
                    block = gz.read(min(_BLOCK, byte_skip - skipped))
                    if not block:
                        break
                    skipped += len(block)
                while len(buf) <= need:
                    block = gz.read(min(_BLOCK, need + 1 - len(buf)))
                    if not block:
                        break
                    buf += block
        except (OSError, EOFError, zlib.error) as exc:
            raise _fail(path, f"corrupt or truncated gzip data: {exc}") from None
    data = memoryview(buf)
    if len(data) != need:
        raise _fail(path, f"{'truncated' if len(data) < need else 'size mismatch'}: {what}"
                          f"expected {need} bytes of decompressed data (shape {shape} of "
                          f"{dtype.name}), got {len(data) if len(data) < need else f'more than {need}'}")
    return np.frombuffer(data, dtype=dtype).reshape(shape)


def write_nrrd(path: Path, vol: np.ndarray, spacing: tuple[float, float, float], *,
               encoding: str = "raw", byte_order: str = "little") -> Path | None:
    """Write ``vol`` (z, y, x) as NRRD; detached (``.nhdr`` + data file) or attached (``.nrrd``).

    Returns the path of the detached data file, or ``None`` for an attached file.
    """
    type_name = _TYPE_NAMES.get(vol.dtype.str[1:])
    if type_name is None:
        raise ParameterError(f"save_volume: NRRD cannot store {vol.dtype} ({path.name}); "
                             "expected an integer type, float32 or float64")
    nz, ny, nx = vol.shape
    sx, sy, sz = (repr(float(s)) for s in spacing)
    lines = ["NRRD0004", "# written by hevr", f"type: {type_name}", "dimension: 3",
             f"sizes: {nx} {ny} {nz}", "space dimension: 3",
             f"space directions: ({sx},0,0) (0,{sy},0) (0,0,{sz})",
             "kinds: domain domain domain", f"endian: {byte_order}", f"encoding: {encoding}"]
    data_path = None
    if path.suffix.lower() == ".nhdr":
        data_path = path.with_suffix(".raw.gz" if encoding == "gzip" else ".raw")
        lines.append(f"data file: {data_path.name}")
        path.write_text("\n".join(lines) + "\n", encoding="ascii")
    with open(data_path or path, "wb") as fh:
        if data_path is None:  # attached: a blank line separates header and data
            fh.write(("\n".join(lines) + "\n\n").encode("ascii"))
        _write_data(fh, vol, byte_order, encoding)
    return data_path
