"""The synthetic test object of the paper (Mazza, Patel, Viola, TVCG 2020, §4).

"Three objects with different densities: a solid cube in the center wrapped inside a
sphere and another sphere at the top left front corner."  The densities are chosen so
that the paper's emphasis densities 0.331, 0.653 and 0.781 each pick out one object.

World axes follow the package convention (see ``API.md``): x = column i, y = row j (up),
z = slice k, and the default camera looks from +z, so "top-left-front" is the octant of
high y, low x and high z.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from ..core.validate import check_int
from ..core.voxels import check_dtype
from ..paper import PAPER_DENSITIES, PAPER_SIZE

__all__ = ["phantom", "PHANTOM_LEVELS"]

_log = logging.getLogger(__name__)

#: Densities of the three objects as fractions of the dtype's range (background is 0).
#: They equal the paper's emphasis densities so that ``density=0.331`` etc. hit them.
PHANTOM_LEVELS: Mapping[str, float] = MappingProxyType(dict(zip(("sphere", "small_sphere", "cube"), PAPER_DENSITIES)))

# Geometry as fractions of ``size``.  The cube's half-diagonal (0.16 * sqrt(3) = 0.277)
# stays inside the outer sphere (0.32), and the small sphere (centre 0.3 per axis from the
# middle, i.e. 0.52 away, radius 0.12) leaves a gap of 0.08 to the outer sphere and 0.08
# to the faces of the box, so the three objects never touch each other or the border.
_SPHERE_RADIUS = 0.32
_CUBE_HALF = 0.16
_SMALL_OFFSET = 0.30
_SMALL_RADIUS = 0.12

# Slabs of z-slices processed at once: bounds the temporaries to ~32 MiB even at 512^3.
_SLAB_VOXELS = 1 << 22


def _level(fraction: float, dtype: np.dtype) -> np.generic:
    """Value at ``fraction`` of the dtype's range ([0, max] for integers, [0, 1] for floats)."""
    value: np.generic
    if dtype.kind == "f":
        value = dtype.type(fraction)
    else:
        # Signed integers use their positive half too: the background must stay 0, and a
        # renderer normalising with (0, max) then sees the same fractions as for unsigned.
        value = dtype.type(round(fraction * np.iinfo(dtype).max))
    return value


def phantom(size: int = PAPER_SIZE, dtype: npt.DTypeLike = np.uint8) -> np.ndarray:
    """Build the paper's test volume: a cube in a sphere plus a small corner sphere.

    Parameters
    ----------
    size : int, default 100
        Edge length in voxels; the result has shape ``(size, size, size)``. At least 4;
        all three objects are resolved from ``size=8`` upwards.
    dtype : numpy dtype, default ``np.uint8``
        Integer or floating-point type of the result. Integer levels are fractions of
        ``[0, iinfo(dtype).max]``; floating-point levels are fractions of ``[0, 1]``.

    Returns
    -------
    numpy.ndarray
        Array of shape ``(size, size, size)`` in (z, y, x) order holding exactly four
        values: 0 (background), 0.331 (outer sphere), 0.781 (centre cube) and 0.653
        (small sphere in the high-z, high-y, low-x octant) of the dtype's range
        (see :data:`PHANTOM_LEVELS`). The result is deterministic.

    Raises
    ------
    ParameterError
        If ``size`` is not an integer >= 4 or ``dtype`` is not an integer/float type.

    Examples
    --------
    >>> import numpy as np
    >>> from hevr.volume.phantom import phantom
    >>> vol = phantom(32)
    >>> vol.shape, vol.dtype
    ((32, 32, 32), dtype('uint8'))
    >>> sorted(np.unique(vol).tolist())
    [0, 84, 167, 199]
    """
    size = check_int("size", size, 4)
    dt = check_dtype(dtype)

    vol = np.zeros((size,) * 3, dtype=dt)
    centre = (size - 1) / 2.0  # exact in binary, so the objects are mirror-symmetric
    big_r2 = (_SPHERE_RADIUS * size) ** 2
    small_r2 = (_SMALL_RADIUS * size) ** 2
    off = _SMALL_OFFSET * size
    # Small sphere centre in index space (k, j, i): high z, high y, low x.
    small_c = (centre + off, centre + off, centre - off)

    _, jj, ii = np.ogrid[0:1, 0:size, 0:size]
    # Per-row/column squared offsets, reused for every slab (broadcast, not materialised).
    dy2, dx2 = (jj - centre) ** 2, (ii - centre) ** 2
    sy2, sx2 = (jj - small_c[1]) ** 2, (ii - small_c[2]) ** 2
    slab = max(1, _SLAB_VOXELS // (size * size))
    sphere_v, small_v = _level(PHANTOM_LEVELS["sphere"], dt), _level(PHANTOM_LEVELS["small_sphere"], dt)
    for k0 in range(0, size, slab):
        kk = np.arange(k0, min(size, k0 + slab), dtype=np.float64)[:, None, None]
        out = vol[k0 : k0 + slab]
        out[(kk - centre) ** 2 + dy2 + dx2 <= big_r2] = sphere_v
        out[(kk - small_c[0]) ** 2 + sy2 + sx2 <= small_r2] = small_v

    # The cube is separable, so a slice assignment paints it exactly and cheaply.
    half = _CUBE_HALF * size
    lo, hi = int(np.ceil(centre - half)), int(np.floor(centre + half))
    vol[lo : hi + 1, lo : hi + 1, lo : hi + 1] = _level(PHANTOM_LEVELS["cube"], dt)
    _log.debug("phantom(size=%d, dtype=%s): cube indices %d..%d", size, dt, lo, hi)
    return vol
