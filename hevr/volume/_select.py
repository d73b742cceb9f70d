"""One 3-D volume out of a 4-D file: the ``volume=`` index shared by every reader.

hevr encrypts one scalar per voxel of one 3-D volume. A file with a fourth axis (fMRI time
points, diffusion directions, vector components, OME-Zarr time) is read only when the
caller picks one index along it; a fourth axis of size 1 needs no choice. The readers
slice the one volume out (a view, or a read of that volume only) before anything else.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ParameterError, VolumeFormatError

__all__ = ["select_index", "reject_index"]


def select_index(
    volume: int | None, count: int, path: Path, what: str = "volumes", axis: str = "its 4th dimension"
) -> int:
    """The index to read along a file's extra axis of ``count`` entries.

    >>> select_index(None, 1, Path("a.nii"))
    0
    >>> select_index(2, 5, Path("a.nii"))
    2
    >>> select_index(None, 5, Path("a.nii"))
    Traceback (most recent call last):
        ...
    hevr.errors.VolumeFormatError: a.nii: holds 5 volumes along its 4th dimension; hevr encrypts one 3-D \
volume: pick one with volume=i (CLI --volume i), 0 <= i < 5
    """
    if volume is None:
        if count == 1:
            return 0
        raise VolumeFormatError(
            f"{path.name}: holds {count} {what} along {axis}; hevr encrypts one 3-D "
            f"volume: pick one with volume=i (CLI --volume i), 0 <= i < {count}"
        )
    if not 0 <= volume < count:
        raise ParameterError(
            f"volume: expected an index in [0, {count - 1}] ({path.name} holds {count} {what}), got {volume}"
        )
    return volume


def reject_index(volume: Any, path: Path) -> None:
    """Refuse ``volume=`` for a file that holds a single 3-D volume."""
    if volume is not None:
        raise ParameterError(
            f"volume: {path.name} holds a single 3-D volume; volume= only applies to 4-D files, got volume={volume!r}"
        )
