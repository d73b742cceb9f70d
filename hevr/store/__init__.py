"""The encrypted store: a Zarr v3 group of ciphertext bricks.

=================  =============================================================
``metadata``       versioned, checksummed, frozen store metadata (``VolumeMetadata``)
``digests``        per-brick digests over ciphertext bytes (crc32c) and public ids
``journal``        owner-side resume journals (a resume cannot mix two volumes)
``paths``          local / fsspec store paths; write beside, then swap
``writer``         ``encrypt_volume``: brick-parallel encryption on Dask
``reader``         ``open_volume`` / :class:`EncryptedVolume`: reading, checked bricks
``upgrade``        ``upgrade_store``: format 1 → format 2 (adds the digests)
=================  =============================================================
"""

from __future__ import annotations

from .reader import EncryptedVolume, open_volume
from .upgrade import upgrade_store
from .writer import encrypt_volume

__all__ = ["EncryptedVolume", "encrypt_volume", "open_volume", "upgrade_store"]
