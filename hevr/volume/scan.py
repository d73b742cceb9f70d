"""What a loader returns: the voxels in hevr's patient frame and the public facts about them.

A :class:`Scan` is the owner-side result of :func:`hevr.read_scan`: the array (RAS+ when the
file records patient geometry, see :mod:`hevr.volume.orientation`), its spacing and origin,
and header facts such as the modality. Nothing here is computed from voxel values, so every
field may go into public metadata.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Scan"]


@dataclass(frozen=True)
class Scan:
    """A loaded volume and the geometry its file recorded.

    Attributes
    ----------
    volume : numpy.ndarray
        Shape (nz, ny, nx), x fastest; a read-only memory map for uncompressed native files.
    spacing : (sx, sy, sz)
        Voxel sizes in world order (mm for medical formats).
    origin : (x0, y0, z0)
        World position of voxel (0, 0, 0); (0, 0, 0) when the file records none.
    frame : "RAS" or None
        ``"RAS"`` when the file recorded patient orientation and the volume was reoriented
        into RAS+; ``None`` when it did not (``.npy``, ``.raw``, TIFF, …): axes as stored.
    modality : str or None
        DICOM-style modality code (``"CT"``, ``"MR"``, ``"PT"``, …) when the file says.
    source : str
        The file or folder read, for messages.
    details : dict
        Format-specific public header facts (series UID, frame count, NRRD encoding, …).
    """

    volume: np.ndarray
    spacing: tuple[float, float, float]
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame: str | None = None
    modality: str | None = None
    source: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:  # never the voxels
        return (
            f"Scan(shape={tuple(self.volume.shape)}, dtype={self.volume.dtype}, spacing={self.spacing}, "
            f"origin={self.origin}, frame={self.frame!r}, modality={self.modality!r}, source={self.source!r})"
        )
