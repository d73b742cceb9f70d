"""Per-brick digests: what makes a store's bricks impossible to corrupt, swap or mix silently.

Each brick of each channel has a SHA-256 digest, written by the task that wrote the brick,
into the brick's completion marker (``done/``, one chunk per brick)::

    digest = SHA-256( "hevr-brick-v2" ‖ store_id ‖ channel ‖ index (3 × int64 LE)
                      ‖ record width (int64 LE) ‖ the brick's ciphertext records, C order )

It is checked whenever a brick is read (:meth:`hevr.EncryptedVolume.read_brick`). So

* a flipped bit or a truncated chunk changes the records → mismatch;
* two swapped bricks (chunks and markers together) differ in ``index`` → mismatch;
* a chunk (with its marker) copied from another store, even one of the same key, differs
  in ``store_id`` (16 random hex digits per store) → mismatch.

Every chunk also carries Zarr's crc32c codec, which covers the whole chunk file, including
the zero padding of edge bricks that no voxel reads. The digest covers **ciphertext bytes
and public identifiers only**: nothing derived from the plaintext or the secret key enters
the store (docs/security.md). It is not a MAC: whoever can write the store can recompute
it; it detects accidents and mix-ups, not a forger.

>>> import numpy as np
>>> recs = np.zeros((2, 1, 1, 4), np.uint8)
>>> d = brick_digest("0123456789abcdef", "scalar", (0, 0, 1), recs)
>>> len(d), d == brick_digest("0123456789abcdef", "scalar", (0, 1, 0), recs)
(32, False)
"""

from __future__ import annotations

import hashlib
import struct

import numpy as np

__all__ = ["DIGEST_BYTES", "brick_digest", "digest_hex"]

DIGEST_BYTES = 32
_DOMAIN = b"hevr-brick-v2\x00"


def brick_digest(store_id: str, channel: str, index: tuple[int, int, int], records: np.ndarray) -> bytes:
    """The 32-byte digest of one brick's records of one channel (module docstring)."""
    arr = np.ascontiguousarray(records, dtype=np.uint8)
    h = hashlib.sha256(_DOMAIN)
    h.update(store_id.encode("ascii") + b"\x00" + channel.encode("ascii") + b"\x00")
    h.update(struct.pack("<4q", *(int(i) for i in index), int(arr.shape[-1]) if arr.ndim else 0))
    h.update(memoryview(arr).cast("B"))
    return h.digest()


def digest_hex(digest: bytes | np.ndarray) -> str:
    """The first 16 hex digits of a digest, for messages.

    >>> digest_hex(bytes(range(32)))
    '0001020304050607'
    """
    return bytes(np.asarray(digest, dtype=np.uint8).tobytes() if not isinstance(digest, bytes) else digest)[:8].hex()
