"""The multi-resolution pyramid's definition: level shapes, geometry and plaintext averaging.

Level 0 is the volume. A voxel of level L+1 is the average of its 2×2×2 children of level L:
children ``(2k+a, 2j+b, 2i+c)``, ``a, b, c ∈ {0, 1}``, where a child index beyond the last
voxel of an axis is clamped to it (the edge voxel counts twice along that axis, as trilinear
sampling clamps its indices). So every coarse voxel is an average of exactly 8 values and

    mean = (Σ children) / 8 = (Σ children) · 125 · 10^-3,

which keeps fixed point exact: a channel of exponent e at level L has exponent e − 3L and its
mantissas are 125 · Σ children mantissas (the encrypted store does this with one ⊕ of 8
ciphertexts and one ⊗ 125: :mod:`hevr.store.pyramid`). A level of shape ``m`` has
``ceil(m/2)`` voxels per axis at the next level.

Geometry. Level-L voxel ``(k, j, i)`` covers level-0 voxels ``[2^L i, 2^L (i+1))`` per axis,
so its centre is at world ``(2^L i + (2^L − 1)/2) · s``: the level's grid has spacing
``2^L · s`` and is offset by ``origin = (2^L − 1)/2 · s`` (world order). A level is rendered
with hevr's origin-at-zero conventions by moving the camera by ``−origin``
(:meth:`hevr.Camera.translated`); the camera the user gives is unchanged.

>>> level_shape((5, 4, 1), 1), level_shape((5, 4, 1), 2)
((3, 2, 1), (2, 1, 1))
>>> level_origin((1.0, 2.0, 0.5), 2)
(1.5, 3.0, 0.75)
>>> downsample(np.arange(3.0).reshape(1, 1, 3)).tolist()   # (0+1)/2, (2+2)/2 along x
[[[0.5, 2.0]]]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.validate import check_int
from ..errors import ParameterError

__all__ = ["MAX_LEVELS", "downsample", "level_brick", "level_origin", "level_shape", "level_spacing", "check_level"]

MAX_LEVELS = 8  # 2^8 = 256 voxels per axis fold into one: more is never useful


def check_level(level: Any, available: int | None = None, name: str = "level") -> int:
    """A pyramid level: an int in [0, MAX_LEVELS], and at most ``available`` when given.

    >>> check_level(1, 2)
    1
    >>> check_level(3, 2)  # doctest: +NORMALIZE_WHITESPACE
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: level: expected a level of this store's pyramid, 0 to 2, got 3 (build more levels
    with hevr.build_pyramid; a packed store's: encrypt_volume(..., levels=))
    """
    level = check_int(name, level, 0, MAX_LEVELS)
    if available is not None and level > available:
        raise ParameterError(
            f"{name}: expected a level of this store's pyramid, 0 to {available}, got {level} "
            "(build more levels with hevr.build_pyramid; a packed store's: "
            "encrypt_volume(..., levels=))"
        )
    return level


def level_shape(shape: Any, level: int) -> tuple[int, int, int]:
    """Array shape (nz, ny, nx) of pyramid level ``level`` of a volume of ``shape``."""
    out = tuple(int(s) for s in shape)
    for _ in range(level):
        out = tuple(-(-s // 2) for s in out)
    return out  # type: ignore[return-value]


def level_brick(brick: Any, level: int) -> tuple[int, int, int]:
    """Brick shape of level ``level``: the base brick (a level has 8^level times fewer bricks,
    each as much work as a base brick's task; on the 2-worker benchmark machine, bricks halved per
    level — as many tasks as level 0 — made coarse frames 1.3–2.4× slower from per-task costs,
    benchmarks/history.md).

    >>> level_brick((25, 25, 25), 2)
    (25, 25, 25)
    """
    return tuple(int(b) for b in brick)  # type: ignore[return-value]


def level_spacing(spacing: Any, level: int) -> tuple[float, float, float]:
    """World-order voxel spacing of level ``level``: ``2^level · spacing``."""
    return tuple(float(s) * 2**level for s in spacing)


def level_origin(spacing: Any, level: int) -> tuple[float, float, float]:
    """World-order centre of level voxel (0, 0, 0): ``(2^level − 1)/2 · spacing``."""
    return tuple(float(s) * (2**level - 1) / 2 for s in spacing)


def downsample(arr: np.ndarray, levels: int = 1) -> np.ndarray:
    """Average 2×2×2 children ``levels`` times (clamped at the edges), over the first three
    axes of ``arr`` (further axes, e.g. the components of an encoded vector, are kept). The
    plaintext definition the encrypted pyramid is checked against; returns float64."""
    out = np.asarray(arr, dtype=np.float64)
    for _ in range(levels):
        pad = [(0, s % 2) for s in out.shape[:3]] + [(0, 0)] * (out.ndim - 3)
        out = np.pad(out, pad, mode="edge")
        z, y, x = (s // 2 for s in out.shape[:3])
        out = out.reshape((z, 2, y, 2, x, 2) + out.shape[3:]).mean(axis=(1, 3, 5))
    return out
