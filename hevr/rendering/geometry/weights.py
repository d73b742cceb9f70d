"""Plaintext per-brick sample weights for the encrypted renderer.

The encrypted renderer never interpolates ciphertexts sample by sample. Instead, for each
brick it receives integer weights ``w`` for (ray, voxel) pairs and computes
``sum w (x) [[value]]`` per ray -- one homomorphic scalar multiplication per distinct pair.
The pixel is then ``(sum over bricks) * 10**exponent / (n * normalisation_factor)``.

Bricks partition the voxel grid: brick ``(bz, by, bx)`` of brick shape ``(B0, B1, B2)``
(array order) owns voxels ``[bz*B0, min((bz+1)*B0, nz)) x ...``. A brick applies weights
only to voxels it owns (no halo), so the per-brick partial weights add up exactly to the
whole-ray weights: for nearest sampling these are counts; for trilinear sampling every
(ray, voxel) pair's float sum is formed from the same samples, by the same shared helpers
(:mod:`hevr.rendering.geometry.rays`), in the same order (corner, then k), whatever the brick split, and
is only then rounded.

Weights
-------
* nearest: ``w`` = number of the ray's samples whose voxel ``floor(p + 0.5)`` (clamped) is
  that voxel; ``exponent = 0``. Exact.
* trilinear: ``w = round(10**digits * W)`` (half up) with ``W`` the sum over the ray's
  samples of that voxel's trilinear corner weight (corners clamped to the same voxel
  add); ``exponent = -digits``. Pairs that round to 0 are dropped.

Quantisation bound (trilinear)
------------------------------
Each pair's weight is off by ``|w*10**-digits - W| <= 0.5*10**-digits`` (a dropped pair
has ``W < 0.5*10**-digits``). A ray with ``n`` samples touches ``P <= 8n`` distinct pairs,
so for any per-voxel quantity ``q`` (raw value, or ``e(density) @ M`` for emphasize/tf)::

    |sum_pairs w*10**-digits*q - sum_pairs W*q| / n <= P * 0.5*10**-digits * max|q| / n
                                                    <= 4 * 10**-digits * max|q|

and dividing also by K for tf only shrinks it. With the default ``digits=3`` an 8-bit
xray pixel is within ``4e-3 * 255 ~= 1.02`` grey levels in the worst case; typical errors
are far smaller because the rounding errors are not all of one sign.

Geometry work per brick is proportional to the samples that can touch it: each ray is
clipped (vectorised, in index space, with a 1e-6 safety margin and one spare sample at
each end) to the brick's region of influence -- ``[k0 - 0.5, k1 - 0.5)`` per axis for
nearest, ``(k0 - 1, k1)`` for trilinear, unbounded on sides at the volume border because
indices are clamped -- and only the samples in that range are generated, then filtered
exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from array_api_compat import array_namespace

from ...core.validate import (
    check_brick,
    check_brick_index,
    check_choice,
    check_int,
    check_shape,
    check_spacing,
    check_step,
)
from ...errors import ParameterError
from ..planning.modes import SAMPLINGS
from .rays import (
    RaySet,
    corner_index,
    expand_samples,
    nearest_voxels,
    sample_positions,
    trilinear_corners,
)

__all__ = ["BrickWeights", "brick_grid", "brick_bounds", "touched_bricks", "brick_weights"]

_CHUNK_SAMPLES = 1 << 18
# Margin (index units) by which a brick's region of influence is widened before the
# per-ray clipping; the clipped sample ranges are a superset and then filtered exactly.
_REGION_EPS = 1e-6
_MAX_DIGITS = 12


@dataclass(frozen=True, eq=False)
class BrickWeights:
    """Integer (ray, voxel) weights of one brick in CSR layout.

    Attributes
    ----------
    brick : tuple (bz, by, bx)
    rays : (R,) int64
        Sorted unique global pixel indices ``row*width + col`` touching the brick (also when
        the ray set is a subset of the image).
    indptr : (R + 1,) int64
        Ray ``rays[r]`` owns entries ``indptr[r]:indptr[r + 1]``.
    voxels : (P,) int64
        Flat C-order indices into the brick's local array (edge bricks may be smaller).
    weights : (P,) int64
        Positive; the weight of a pair is ``weights * 10**exponent``.
    exponent : int
        0 for nearest, ``-digits`` for trilinear.
    """

    brick: tuple[int, int, int]
    rays: np.ndarray
    indptr: np.ndarray
    voxels: np.ndarray
    weights: np.ndarray
    exponent: int

    @property
    def n_pairs(self) -> int:
        """Number of stored (ray, voxel) pairs."""
        return int(self.weights.shape[0])

    def apply(self, local_values: np.ndarray) -> np.ndarray:
        """Plaintext check: per-ray ``sum w * 10**exponent * value``, shape (R,) + trailing.

        Examples
        --------
        >>> bw = BrickWeights((0, 0, 0), np.array([4]), np.array([0, 2]), np.array([0, 1]),
        ...                   np.array([2, 1]), 0)
        >>> bw.apply(np.array([[[10.0, 1.0]]])).tolist()
        [21.0]
        """
        vals = np.asarray(local_values, dtype=np.float64)
        flat = vals.reshape((-1,) + vals.shape[3:])
        contrib = flat[self.voxels] * self.weights.reshape((-1,) + (1,) * (flat.ndim - 1))
        if self.n_pairs == 0:
            return np.zeros((0,) + flat.shape[1:])
        return np.add.reduceat(contrib, self.indptr[:-1], axis=0) * 10.0**self.exponent


def brick_grid(shape: Any, brick: Any) -> tuple[int, int, int]:
    """Number of bricks per array axis.

    Examples
    --------
    >>> brick_grid((7, 9, 11), (3, 4, 5))
    (3, 3, 3)
    """
    return _grid(check_shape(shape), check_brick(brick))


def _grid(shape: tuple[int, int, int], brick: tuple[int, int, int]) -> tuple[int, int, int]:
    z, y, x = (-(-n // b) for n, b in zip(shape, brick))
    return z, y, x


def brick_bounds(shape: Any, brick: Any, brick_index: Any) -> tuple[tuple[int, int], ...]:
    """Owned voxel ranges ``((z0, z1), (y0, y1), (x0, x1))`` (half open) of one brick.

    Examples
    --------
    >>> brick_bounds((7, 9, 11), (3, 4, 5), (2, 0, 2))
    ((6, 7), (0, 4), (10, 11))
    """
    return _bounds(check_shape(shape), check_brick(brick), brick_index)


def _bounds(shape: tuple[int, int, int], brick: tuple[int, int, int], brick_index: Any) -> tuple[tuple[int, int], ...]:
    """:func:`brick_bounds` of a checked shape and brick; checks only the brick index."""
    idx = check_brick_index(brick_index, _grid(shape, brick))
    return tuple((i * b, min((i + 1) * b, n)) for i, b, n in zip(idx, brick, shape))


def _check_request(rays: Any, shape: Any, spacing: Any, brick: Any, sampling: Any, step: Any):
    """Check the arguments :func:`touched_bricks` and :func:`brick_weights` share, once."""
    if not isinstance(rays, RaySet):
        raise ParameterError(f"rays: expected a hevr.rendering.geometry.rays.RaySet, got {type(rays).__name__}")
    check_choice("sampling", sampling, SAMPLINGS)
    return check_shape(shape), np.asarray(check_spacing(spacing)), check_brick(brick), check_step(step)


def touched_bricks(
    rays: RaySet, shape: Any, spacing: Any, brick: Any, sampling: str, step: float
) -> list[tuple[int, int, int]]:
    """Sorted brick indices (bz, by, bx) owning a voxel some sample gives positive weight.

    Exactly the bricks with non-empty :func:`brick_weights` for nearest; for trilinear a
    brick whose every pair rounds to 0 is still listed (its weights are then empty).

    Examples
    --------
    >>> from hevr.rendering.geometry.camera import Camera
    >>> from hevr.rendering.geometry.rays import cast_rays
    >>> cam = Camera((2, 2, 9), (2, 2, 0), width=1, height=1, parallel=True)
    >>> rs = cast_rays(cam, (5, 5, 5), (1, 1, 1), 1.0)
    >>> touched_bricks(rs, (5, 5, 5), (1, 1, 1), 3, "nearest", 1.0)
    [(0, 0, 0), (1, 0, 0)]
    """
    shape, sp, brick, step = _check_request(rays, shape, spacing, brick, sampling, step)
    bshape = np.array(brick[::-1], dtype=np.int64)  # (i, j, k) order
    gx, gy, _ = _grid(shape, brick)[::-1]
    bstride = np.array([1, gx, gx * gy], dtype=np.int64)
    hits = np.flatnonzero(rays.n_samples > 0)
    counts = rays.n_samples[hits]
    found: set[int] = set()
    csum = np.concatenate(([0], np.cumsum(counts)))
    start = 0
    while start < hits.size:
        end = max(int(np.searchsorted(csum, csum[start] + _CHUNK_SAMPLES, side="right")) - 1, start + 1)
        ray_idx, k = expand_samples(hits[start:end], np.zeros(end - start, dtype=np.int64), counts[start:end])
        p = sample_positions(rays, ray_idx, k, sp, step)
        if sampling == "nearest":
            ids = (nearest_voxels(p, shape) // bshape) @ bstride
        else:
            lo, hi, w = trilinear_corners(p, shape)
            blo = lo // bshape
            cross = np.any(blo != hi // bshape, axis=1)
            parts = [blo[~cross] @ bstride]
            if cross.any():
                lo, hi, w = lo[cross], hi[cross], w[cross]
                for c in range(8):
                    keep = w[:, c] > 0
                    parts.append((corner_index(lo[keep], hi[keep], c) // bshape) @ bstride)
            ids = np.concatenate(parts)
        found.update(np.unique(ids).tolist())
        start = end
    return [(i // (gx * gy), (i // gx) % gy, i % gx) for i in sorted(found)]


def _clip_rays(rays: RaySet, sp: np.ndarray, step: float, lo: np.ndarray, hi: np.ndarray):
    """Per hit ray, the range of sample indices k whose position may lie in [lo, hi].

    ``lo``/``hi`` are per-axis index-space bounds (i, j, k order, may be infinite). The
    linear model ``p(k) = e + k*delta`` differs from :func:`sample_positions` only by
    rounding (~1e-12), which the widened region and one spare k at each end absorb.
    """
    xp = array_namespace(rays.n_samples)
    hits = xp.nonzero(rays.n_samples > 0)[0]
    n = xp.astype(xp.take(rays.n_samples, hits), xp.float64)
    e = sample_positions(rays, hits, xp.zeros_like(hits), sp, step)
    spx = xp.asarray([float(v) for v in sp], dtype=xp.float64)
    delta = xp.take(rays.directions, hits, axis=0) * float(step) / spx
    lo_e = xp.asarray([float(v) for v in lo], dtype=xp.float64) - _REGION_EPS
    hi_e = xp.asarray([float(v) for v in hi], dtype=xp.float64) + _REGION_EPS
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a, b = (lo_e - e) / delta, (hi_e - e) / delta
    zero = delta == 0
    inside = (e >= lo_e) & (e <= hi_e)
    inf = xp.full_like(a, xp.inf)
    kmin = xp.max(xp.where(zero, xp.where(inside, -inf, inf), xp.minimum(a, b)), axis=1)
    kmax = xp.min(xp.where(zero, xp.where(inside, inf, -inf), xp.maximum(a, b)), axis=1)
    # Clip in float before casting so infinities never reach the int conversion.
    ka = xp.astype(xp.minimum(xp.maximum(xp.ceil(kmin) - 1, 0.0), n), xp.int64)  # np.clip's arithmetic
    kb = xp.astype(xp.minimum(xp.maximum(xp.floor(kmax) + 1, -1.0), n - 1), xp.int64)
    counts = xp.maximum(kb - ka + 1, 0)
    keep = counts > 0
    return hits[keep], ka[keep], counts[keep]


def brick_weights(
    rays: RaySet,
    shape: Any,
    spacing: Any,
    brick: Any,
    brick_index: Any,
    sampling: str,
    step: float,
    digits: int = 3,
) -> BrickWeights:
    """The integer (ray, voxel) weights of one brick; see the module docstring.

    Parameters
    ----------
    rays : RaySet
        From :func:`hevr.rendering.geometry.rays.cast_rays` with the same shape, spacing and step.
    shape : (nz, ny, nx)
    spacing : (sx, sy, sz)
    brick : int or (B0, B1, B2)
        Brick shape in array order.
    brick_index : (bz, by, bx)
    sampling : {'nearest', 'trilinear'}
    step : float
    digits : int, default 3
        Decimal digits of the trilinear weights (ignored for nearest).

    Examples
    --------
    >>> from hevr.rendering.geometry.camera import Camera
    >>> from hevr.rendering.geometry.rays import cast_rays
    >>> cam = Camera((2, 2, 9), (2, 2, 0), width=1, height=1, parallel=True)
    >>> rs = cast_rays(cam, (5, 5, 5), (1, 1, 1), 1.0)
    >>> bw = brick_weights(rs, (5, 5, 5), (1, 1, 1), 3, (1, 0, 0), "nearest", 1.0)
    >>> bw.rays.tolist(), bw.voxels.tolist(), bw.weights.tolist()
    ([0], [8, 17], [1, 1])
    """
    shape, sp, brick, step = _check_request(rays, shape, spacing, brick, sampling, step)
    digits = check_int("digits", digits, 0, _MAX_DIGITS)
    bounds = _bounds(shape, brick, brick_index)
    bz, by, bx = (int(i) for i in brick_index)
    index = (bz, by, bx)
    v0 = np.array([b[0] for b in bounds[::-1]], dtype=np.int64)  # (i, j, k) order
    v1 = np.array([b[1] for b in bounds[::-1]], dtype=np.int64)
    full = np.array(shape[::-1], dtype=np.int64)
    local = v1 - v0
    lstride = np.array([1, local[0], local[0] * local[1]], dtype=np.int64)
    nloc = int(np.prod(local))
    # Region of influence; open-ended at the volume border where indices clamp.
    if sampling == "nearest":
        lo, hi = v0 - 0.5, v1 - 0.5
    else:
        lo, hi = v0 - 1.0, v1.astype(np.float64)
    lo = np.where(v0 == 0, -np.inf, lo)
    hi = np.where(v1 == full, np.inf, hi)
    ray_ids, ka, counts = _clip_rays(rays, sp, step, lo, hi)

    keys_parts: list[np.ndarray] = []
    w_parts: list[np.ndarray] = []  # trilinear only (nearest sampling counts pairs)
    csum = np.concatenate(([0], np.cumsum(counts)))
    start = 0
    while start < ray_ids.size:
        end = max(int(np.searchsorted(csum, csum[start] + _CHUNK_SAMPLES, side="right")) - 1, start + 1)
        r, k = expand_samples(ray_ids[start:end], ka[start:end], counts[start:end])
        p = sample_positions(rays, r, k, sp, step)
        if sampling == "nearest":
            corners: list[tuple[np.ndarray, np.ndarray | None]] = [(nearest_voxels(p, shape), None)]
        else:
            clo, chi, cw = trilinear_corners(p, shape)
            corners = [(corner_index(clo, chi, c), cw[:, c]) for c in range(8)]
        for idx, w in corners:
            own = np.all((idx >= v0) & (idx < v1), axis=1)
            if w is not None:
                own &= w > 0
                w_parts.append(w[own])
            keys_parts.append(r[own] * nloc + (idx[own] - v0) @ lstride)
        start = end

    keys = np.concatenate(keys_parts) if keys_parts else np.zeros(0, dtype=np.int64)
    if sampling == "nearest":
        pairs, wts = np.unique(keys, return_counts=True)
        wts = wts.astype(np.int64)
        exponent = 0
    else:
        # Chunks are ray-major and corners within a chunk corner-major, so every pair's
        # contributions are summed in (corner, k) order regardless of the brick split.
        wcat = np.concatenate(w_parts) if w_parts else np.zeros(0)
        pairs, inverse = np.unique(keys, return_inverse=True)
        total = np.bincount(inverse.reshape(-1), weights=wcat, minlength=pairs.size)
        wts = np.floor(total * 10.0**digits + 0.5).astype(np.int64)
        nonzero = wts > 0
        pairs, wts = pairs[nonzero], wts[nonzero]
        exponent = -int(digits)
    pair_rays = pairs // nloc
    uniq, first = np.unique(pair_rays, return_index=True)
    indptr = np.append(first, pairs.size).astype(np.int64)
    return BrickWeights(
        brick=index,
        rays=rays.global_ids(uniq),
        indptr=indptr,
        voxels=(pairs % nloc).astype(np.int64),
        weights=wts,
        exponent=exponent,
    )
