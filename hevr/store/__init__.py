"""The encrypted store: a Zarr v3 group of ciphertext bricks.

==================== ============================================================================
``metadata``         versioned, checksummed, frozen store metadata (``VolumeMetadata``)
``metadata_parts``   its parts: a channel's fixed point, a pyramid level
``metadata_fields``  the field readers that name the field that is wrong
``metadata_parse``   the strict reading of the ``hevr`` attribute, every field validated
``digests``          per-brick digests over ciphertext bytes (crc32c) and public ids
``journal``          owner-side resume journals (a resume cannot mix two volumes)
``paths``            local / fsspec store paths and documents
``replacing``        replacing a store: write beside, then swap
``exclusive``        one writer per store: atomic claims, store locks, stale temporaries
``creation``         ``claim_store``: a new store, exactly one of concurrent creators wins
``quantise``         the channels' fixed point, planned by the owner; a brick's mantissas
``store_plan``       ``encrypt_volume``'s options checked into the metadata of the store to write
``brick_write``      one encryption task: a brick's ciphertexts, tags and digest marker
``writer``           ``encrypt_volume``: brick-parallel encryption on Dask
``layout``           the arrays of a store and the checks that a store on disk has them
``zstd_frame``       a zstd chunk's exact length from its block headers (the size checks)
``brick_read``       one brick read and checked: records, digest, ciphertext range
``reader``           ``open_volume`` / :class:`EncryptedVolume`: opening, bricks, levels
``verify``           the full check: every brick of every channel read back and named if damaged
``resident``         resident volumes: decoded bricks in worker memory
``pyramid``          ``build_pyramid``: the encrypted multi-resolution pyramid (server side)
``upgrade``          ``upgrade_store``: format 1 → format 2 (adds the digests)
==================== ============================================================================
"""

from __future__ import annotations

from .pyramid import build_pyramid
from .reader import EncryptedVolume, open_volume
from .upgrade import upgrade_store
from .writer import encrypt_volume

__all__ = ["EncryptedVolume", "build_pyramid", "encrypt_volume", "open_volume", "upgrade_store"]
