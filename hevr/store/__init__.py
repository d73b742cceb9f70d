"""The encrypted store: a Zarr v3 group of ciphertext bricks.

=================  =============================================================
``metadata``       versioned, frozen store metadata (``VolumeMetadata``)
``writer``         ``encrypt_volume``: brick-parallel encryption on Dask
``reader``         ``open_volume`` / :class:`EncryptedVolume`: reading bricks
=================  =============================================================
"""

from __future__ import annotations

from .reader import EncryptedVolume, open_volume
from .writer import encrypt_volume

__all__ = ["EncryptedVolume", "encrypt_volume", "open_volume"]
