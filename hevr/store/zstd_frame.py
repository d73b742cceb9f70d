"""The length of a zstd frame read from its block headers (RFC 8878 §3.1.1): how the size of a
zstd brick chunk of a local store is checked exactly without decompressing it
(:func:`hevr.store.layout.check_chunk_files`); a file that is not one complete frame is a
:class:`DamagedFrame` saying why.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

from ..core.files import file_kind

__all__ = ["DamagedFrame", "frame_length"]

_ZSTD_MAGIC = 0xFD2FB528
_ZSTD_FCS_BYTES = (0, 2, 4, 8)  # by Frame_Content_Size_flag (flag 0: 1 byte if single segment)
_ZSTD_DICT_BYTES = (0, 1, 2, 4)


_ZSTD_BLOCK = 128 << 10  # Block_Maximum_Size: a raw block holds at most 128 KiB


class DamagedFrame(Exception):
    """A chunk file that is not one complete zstd frame; the message says what is wrong, in
    words for a user (the caller names the store, the chunk and the brick)."""


def frame_length(f: Path, content: int, observed: int = -1) -> int:
    """Bytes of the single zstd frame at the start of ``f`` (RFC 8878 §3.1.1); raises
    :class:`DamagedFrame` saying why when the file does not start with such a frame of
    ``content`` bytes (no magic number, another content size, a block header cut off by the
    end of the file, a reserved block type).

    A brick of ciphertexts only (no padding) is stored as full raw blocks: when ``observed``
    (the file's frame bytes) is exactly that length and the first block is such a raw block,
    the frame's length is known from its header alone; otherwise (edge bricks, damage) the
    block headers are walked, one 3-byte read per block. The file is opened without blocking
    and must be a regular file (a FIFO put in its place raises, it never hangs)."""
    try:
        fd = os.open(f, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise DamagedFrame(f"it cannot be opened: {exc.strerror}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise DamagedFrame(f"it is {file_kind(mode)}, not a regular file")
        os.set_blocking(fd, True)
        with os.fdopen(os.dup(fd), "rb", buffering=0) as fh:
            return _walk_frame(fh, content, observed)
    except OSError as exc:
        raise DamagedFrame(f"it cannot be read: {exc.strerror}") from None
    finally:
        os.close(fd)


def _walk_frame(fh: Any, content: int, observed: int) -> int:
    """:func:`frame_length` on an open file."""
    head = fh.read(18)
    if len(head) < 6:
        raise DamagedFrame(f"the file holds {len(head)} bytes, too few for a zstd frame header (truncated)")
    if int.from_bytes(head[:4], "little") != _ZSTD_MAGIC:
        raise DamagedFrame(
            f"it does not start with the zstd magic number (its first bytes are {head[:4].hex()}, expected 28b52ffd)"
        )
    fhd = head[4]
    single, fcs_flag = (fhd >> 5) & 1, fhd >> 6
    pos = 5 + (0 if single else 1) + _ZSTD_DICT_BYTES[fhd & 3]
    fcs_len = _ZSTD_FCS_BYTES[fcs_flag] or (1 if single else 0)
    if fcs_len:
        if len(head) < pos + fcs_len:
            raise DamagedFrame(f"the file ends inside the frame header after {len(head)} bytes (truncated)")
        fcs = int.from_bytes(head[pos : pos + fcs_len], "little") + (256 if fcs_len == 2 else 0)
        if fcs != content:
            raise DamagedFrame(f"its header says the brick holds {fcs} bytes, expected {content}")
    pos += fcs_len
    raw = pos + 3 * -(-content // _ZSTD_BLOCK) + content
    if observed == raw and content:
        fh.seek(pos)
        first = int.from_bytes(fh.read(3), "little")
        if (first >> 1) & 3 == 0 and first >> 3 == min(content, _ZSTD_BLOCK):
            return raw
    while True:
        fh.seek(pos)
        block = fh.read(3)
        if len(block) < 3:
            total = os.fstat(fh.fileno()).st_size
            raise DamagedFrame(f"a block header was due at byte {pos}, but the file has {total} bytes (truncated)")
        bh = int.from_bytes(block, "little")
        last, kind, size = bh & 1, (bh >> 1) & 3, bh >> 3
        if kind == 3:
            raise DamagedFrame(f"the block header at byte {pos} has the reserved block type 3 (overwritten data)")
        pos += 3 + (1 if kind == 1 else size)
        if last:
            return pos + (4 if fhd & 4 else 0)
