"""The encrypted store: a Zarr v3 group of ciphertext bricks.

=================  =============================================================
``metadata``       versioned, checksummed, frozen store metadata (``VolumeMetadata``)
``digests``        per-brick digests over ciphertext bytes (crc32c) and public ids
``journal``        owner-side resume journals (a resume cannot mix two volumes)
``paths``          local / fsspec store paths; write beside, then swap
``exclusive``      one writer per store: atomic claims, store locks, stale temporaries
``creation``       ``claim_store``: a new store, exactly one of concurrent creators wins
``quantise``       the channels' fixed point, planned by the owner; a brick's mantissas
``writer``         ``encrypt_volume``: brick-parallel encryption on Dask
``layout``         the arrays of a store and the checks that a store on disk has them
``reader``         ``open_volume`` / :class:`EncryptedVolume`: reading, checked bricks, levels
``verify``         the full check: every brick of every channel read back and named if damaged
``resident``       resident volumes: decoded bricks in worker memory
``pyramid``        ``build_pyramid``: the encrypted multi-resolution pyramid (server side)
``upgrade``        ``upgrade_store``: format 1 → format 2 (adds the digests)
=================  =============================================================
"""

from __future__ import annotations

from .pyramid import build_pyramid
from .reader import EncryptedVolume, open_volume
from .upgrade import upgrade_store
from .writer import encrypt_volume

__all__ = ["EncryptedVolume", "build_pyramid", "encrypt_volume", "open_volume", "upgrade_store"]
