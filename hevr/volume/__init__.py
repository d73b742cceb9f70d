"""Plaintext volumes, before encryption: loaders, the phantom, density normalisation and the
Alg. 4 vector encoding.

=================  =============================================================
``loaders``        ``read_scan`` (one dispatcher) / ``load_volume`` / ``save_volume``
``scan``           ``Scan``: a loaded volume, its spacing, origin, frame and modality
``orientation``    hevr's RAS+ patient frame: reorienting views of the stored axes
``nrrd``           the NRRD reader/writer; ``nrrd_space`` its geometry
``raw``            headerless raw files (layout in the name), memory-mapped raw data
``nifti``          NIfTI and FreeSurfer MGH/MGZ (nibabel)
``dicom``          DICOM series, DICOMDIR and multi-frame files (pydicom); ``dicom_*`` its parts
``tiff``           TIFF stacks, OME-TIFF, ImageJ hyperstacks (tifffile)
``zarr_input``     plaintext Zarr arrays and OME-Zarr images
``phantom``        the paper's synthetic phantom
``density``        value range -> [0, 1] densities, Alg. 4 encoding
``gradient``       the gradient channel g·e(d): gradient-magnitude modulation (owner side)
``modality``       value ranges and transfer-function presets per modality (CT, MR, ...)
=================  =============================================================
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..core.lazy import attach

if TYPE_CHECKING:
    from .density import encode_density, normalize_density
    from .gradient import gradient_encoding
    from .loaders import load_volume, read_scan, save_volume
    from .modality import (
        MODALITY_RANGES,
        TF_PRESETS,
        modality_range,
        range_hint,
        tf_preset,
        window_density,
    )
    from .scan import Scan

# Eager, and light (numpy): hevr.volume.phantom stays the function even once the submodule of
# that name is imported (a lazy name that is also a submodule would be either; hevr.core.lazy.attach).
from .phantom import PHANTOM_LEVELS, phantom  # noqa: E402

__all__ = [
    "PHANTOM_LEVELS",
    "encode_density",
    "gradient_encoding",
    "load_volume",
    "normalize_density",
    "phantom",
    "save_volume",
    "MODALITY_RANGES",
    "TF_PRESETS",
    "modality_range",
    "range_hint",
    "tf_preset",
    "window_density",
    "read_scan",
    "Scan",
]

_LAZY = {
    ".density": ("encode_density", "normalize_density"),
    ".gradient": ("gradient_encoding",),
    ".loaders": ("load_volume", "read_scan", "save_volume"),
    ".modality": ("MODALITY_RANGES", "TF_PRESETS", "modality_range", "range_hint", "tf_preset", "window_density"),
    ".scan": ("Scan",),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
