"""Plaintext volumes, before encryption: loaders, the phantom, density normalisation and the
Alg. 4 vector encoding.

=================  =============================================================
``loaders``        ``load_volume`` / ``save_volume``: .npy, raw, NRRD, NIfTI, DICOM
``nrrd``           the NRRD reader/writer (memory-mapped raw data)
``phantom``        the paper's synthetic phantom
``density``        value range -> [0, 1] densities, Alg. 4 encoding
``gradient``       the gradient channel g·e(d): gradient-magnitude modulation (owner side)
=================  =============================================================
"""

from __future__ import annotations

from .density import encode_density, normalize_density
from .gradient import gradient_encoding
from .loaders import load_volume, save_volume
from .phantom import PHANTOM_LEVELS, phantom

__all__ = ["PHANTOM_LEVELS", "encode_density", "gradient_encoding", "load_volume", "normalize_density", "phantom", "save_volume"]
