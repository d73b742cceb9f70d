"""Per-brick digests: what makes a store's bricks impossible to corrupt, swap or mix silently.

Each brick of each channel has a 32-byte digest, written by the task that wrote the brick,
into the brick's completion marker (``done/``, one chunk per brick)::

    digest = SHA-256( "hevr-brick-v2" ‖ store_id ‖ channel ‖ index (3 × int64 LE)
                      ‖ record width (int64 LE) ‖ byte count (int64 LE)
                      ‖ crc32c of the brick's ciphertext records, C order (uint32 BE) )

It is checked whenever a brick is read (:meth:`hevr.EncryptedVolume.read_brick`). So

* a changed byte, or any error burst of up to 32 bits, changes the crc32c → mismatch,
  always; other random damage passes with probability 2^-32 (and a damaged ciphertext that
  still reached a pixel would then fail the client's range check, 2^-64);
* a truncated chunk changes the byte count → mismatch;
* two swapped bricks (chunks and markers together) differ in ``index`` → mismatch;
* a chunk (with its marker) copied from another store, even one of the same key, differs
  in ``store_id`` (16 random hex digits per store) → mismatch.

Why crc32c inside, not SHA-256 over every byte: this is an accident detector, not a MAC —
it uses no secret, so whoever can write the store can recompute it either way, and a
cryptographic hash of the data would add strength only against a forger it cannot stop.
SHA-256 over the 8 MB of a 2048-bit 25³ brick cost 3.1 % of the workers' time in a nearest
render of the paper case (benchmarks/history.md); the crc32c (hardware, ~6 GB/s) about a
quarter of that. Every chunk also carries Zarr's crc32c codec, which covers the whole chunk
file, including the zero padding of edge bricks that no voxel reads. The digest covers
**ciphertext bytes and public identifiers only**: nothing derived from the plaintext or the
secret key enters the store (docs/security.md).

>>> import numpy as np
>>> recs = np.zeros((2, 1, 1, 4), np.uint8)
>>> d = brick_digest("0123456789abcdef", "scalar", (0, 0, 1), recs)
>>> len(d), d == brick_digest("0123456789abcdef", "scalar", (0, 1, 0), recs)
(32, False)
>>> flipped = recs.copy(); flipped[1, 0, 0, 3] ^= 1
>>> d == brick_digest("0123456789abcdef", "scalar", (0, 0, 1), flipped)
False
"""

from __future__ import annotations

import hashlib
import struct
from typing import Any

import google_crc32c
import numpy as np

__all__ = ["DIGEST_BYTES", "brick_digest", "digest_hex", "marker", "written"]

DIGEST_BYTES = 32
_DOMAIN = b"hevr-brick-v2\x00"


def brick_digest(store_id: str, channel: str, index: tuple[int, int, int], records: np.ndarray) -> bytes:
    """The 32-byte digest of one brick's records of one channel (module docstring)."""
    data = np.ascontiguousarray(records, dtype=np.uint8).tobytes()
    h = hashlib.sha256(_DOMAIN)
    h.update(store_id.encode("ascii") + b"\x00" + channel.encode("ascii") + b"\x00")
    width = int(records.shape[-1]) if np.ndim(records) else 0
    h.update(struct.pack("<5q", *(int(i) for i in index), width, len(data)))
    h.update(struct.pack(">I", google_crc32c.value(data)))
    return h.digest()


def marker(digests: list[bytes]) -> np.ndarray:
    """The ``done`` entry of one brick: its channels' digests as a (C, 32) uint8 array."""
    return np.frombuffer(b"".join(digests), np.uint8).reshape(len(digests), DIGEST_BYTES)


def written(done: Any) -> np.ndarray:
    """Which bricks have their digests: ``done`` (..., C, 32) -> bool (...); all-zero = not written.

    >>> written(np.zeros((2, 1, 1, 2, 32), np.uint8)).tolist()
    [[[False]], [[False]]]
    """
    arr = np.asarray(done)
    return np.asarray(arr.reshape(arr.shape[:-2] + (-1,)).any(axis=-1))


def digest_hex(digest: bytes | np.ndarray) -> str:
    """The first 16 hex digits of a digest, for messages.

    >>> digest_hex(bytes(range(32)))
    '0001020304050607'
    """
    return bytes(np.asarray(digest, dtype=np.uint8).tobytes() if not isinstance(digest, bytes) else digest)[:8].hex()
