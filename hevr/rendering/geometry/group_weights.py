"""Nearest-sampling weights of many bricks at once: one pass over the samples, no sort.

:func:`hevr.rendering.geometry.weights.brick_weights` builds one brick's (ray, voxel) weights: it clips
every ray to the brick, generates the samples there and counts them per pair with
``np.unique`` — a fixed cost of about 2 ms per brick, and a sort. A map task that holds many
resident bricks (:func:`hevr.rendering.pipeline.maps.map_group`) needs the weights of all of them for
the same rays; this module makes them in one pass:

1. every ray is clipped once, to the box of the group's bricks (the region of influence of
   nearest sampling, as :func:`~hevr.rendering.geometry.weights.brick_weights` does per brick), and its
   samples are generated ray-major, k ascending, by the shared
   :func:`~hevr.rendering.geometry.rays.sample_positions` and
   :func:`~hevr.rendering.geometry.rays.nearest_voxels` — so every sample is where the per-brick path
   puts it, bit for bit;
2. each sample gets its brick and its index in that brick's local array; samples of bricks
   outside the group are dropped;
3. **run-length counting instead of sorting.** The samples of one ray that land in one voxel
   are consecutive: the voxel's cell ``[v − 0.5, v + 0.5)`` per axis (a half-line at the
   clamped border) is convex and the samples lie on a line, in order. So the (ray, voxel)
   pairs are the runs of equal (ray, brick, local index) in the sample sequence, and a pair's
   weight — the number of its samples — is its run's length: O(samples), where ``np.unique``
   is O(samples · log samples);
4. the runs are grouped by brick with a stable sort on the brick number (few distinct values:
   a radix sort), which keeps them ray-major: each brick's rows are its rays, ascending.

The weights equal :func:`~hevr.rendering.geometry.weights.brick_weights`'s pair for pair; only the order
of a row's pairs differs (sample order instead of voxel order), which no product depends on
(multiplication mod n² commutes). Trilinear weights are float sums whose rounding depends on
the order of their terms (corner, then k) and keep the per-brick path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from array_api_compat import array_namespace

from ..pipeline._segments import to_host
from .rays import RaySet, expand_samples, nearest_voxels, sample_positions
from .weights import BrickWeights, _bounds, _check_request, _clip_rays, brick_grid

__all__ = ["GroupRows", "nearest_group_rows", "nearest_group_weights"]

_CHUNK_SAMPLES = 1 << 19


@dataclass(frozen=True, eq=False)
class GroupRows:
    """The nearest-sampling (ray, voxel) pairs of a group of bricks, one CSR row per ray.

    Attributes
    ----------
    indices : list of (bz, by, bx)
        The group's bricks, in the caller's order.
    rays : (R,) int64
        Global pixel ids of the rows, ascending.
    indptr : (R + 1,) int64
        Row ``r`` is ``indptr[r]:indptr[r + 1]``: the ray's pairs in sample order, across bricks.
    brick : (P,) int64
        Position in ``indices`` of each pair's brick.
    local : (P,) int64
        Each pair's voxel in its brick's local array (C order).
    weights : (P,) int64
        Samples of the ray in that voxel (positive).
    """

    indices: list
    rays: np.ndarray
    indptr: np.ndarray
    brick: np.ndarray
    local: np.ndarray
    weights: np.ndarray

    def voxels(self, sizes: Any) -> np.ndarray:
        """Each pair's voxel in the concatenation of the bricks' arrays, ``sizes`` voxels each
        (in ``indices`` order): what a product plan over the whole group indexes.

        >>> g = GroupRows([(0, 0, 0), (0, 0, 1)], np.array([0]), np.array([0, 2]), np.array([1, 0]),
        ...               np.array([3, 3]), np.array([1, 1]))
        >>> g.voxels([8, 4]).tolist()
        [11, 3]
        """
        base = np.concatenate(([0], np.cumsum(np.asarray(sizes, np.int64))[:-1]))
        return base[self.brick] + self.local

    def per_brick(self) -> dict[tuple[int, int, int], BrickWeights]:
        """The same pairs as one :class:`BrickWeights` per brick (rows: that brick's rays)."""
        n = len(self.indices)
        order = np.argsort(self.brick.astype(np.uint32 if n >= 1 << 16 else np.uint16), kind="stable")
        ends = np.cumsum(np.bincount(self.brick, minlength=n))
        pair_ray = np.repeat(self.rays, np.diff(self.indptr))[order]
        local, weight = self.local[order], self.weights[order]
        out = {}
        for i, idx in enumerate(self.indices):
            a, e = int(ends[i - 1]) if i else 0, int(ends[i])
            rr = pair_ray[a:e]
            row = np.flatnonzero(np.concatenate(([True], rr[1:] != rr[:-1]))) if rr.size else np.zeros(0, np.int64)
            out[idx] = BrickWeights(
                brick=idx,
                rays=rr[row],
                indptr=np.append(row, rr.size).astype(np.int64),
                voxels=local[a:e],
                weights=weight[a:e],
                exponent=0,
            )
        return out


def nearest_group_weights(
    rays: RaySet, shape: Any, spacing: Any, brick: Any, indices: list, step: float
) -> dict[tuple[int, int, int], BrickWeights]:
    """The nearest-sampling :class:`BrickWeights` of every brick in ``indices``, in one pass
    (:func:`nearest_group_rows`, then grouped by brick).

    Parameters are those of :func:`hevr.rendering.geometry.weights.brick_weights` (``indices``: a list
    of brick indices (bz, by, bx)). A brick that no ray reaches gets an empty entry.

    Examples
    --------
    >>> from hevr.rendering.geometry.camera import Camera
    >>> from hevr.rendering.geometry.rays import cast_rays
    >>> cam = Camera((2, 2, 9), (2, 2, 0), width=1, height=1, parallel=True)
    >>> rs = cast_rays(cam, (5, 5, 5), (1, 1, 1), 1.0)
    >>> w = nearest_group_weights(rs, (5, 5, 5), (1, 1, 1), 3, [(1, 0, 0), (0, 0, 0)], 1.0)
    >>> w[(1, 0, 0)].voxels.tolist(), w[(1, 0, 0)].weights.tolist(), w[(0, 0, 0)].voxels.tolist()
    ([17, 8], [1, 1], [26, 17, 8])
    """
    return nearest_group_rows(rays, shape, spacing, brick, indices, step).per_brick()


def nearest_group_rows(rays: RaySet, shape: Any, spacing: Any, brick: Any, indices: list, step: float) -> GroupRows:
    """The nearest-sampling pairs of the bricks ``indices``, one row per ray (module docstring).

    >>> from hevr.rendering.geometry.camera import Camera
    >>> from hevr.rendering.geometry.rays import cast_rays
    >>> cam = Camera((2, 2, 9), (2, 2, 0), width=1, height=1, parallel=True)
    >>> rs = cast_rays(cam, (5, 5, 5), (1, 1, 1), 1.0)
    >>> g = nearest_group_rows(rs, (5, 5, 5), (1, 1, 1), 3, [(1, 0, 0), (0, 0, 0)], 1.0)
    >>> g.rays.tolist(), g.indptr.tolist(), g.brick.tolist(), g.local.tolist()
    ([0], [0, 5], [0, 0, 1, 1, 1], [17, 8, 26, 17, 8])
    """

    shape, sp, brick, step = _check_request(rays, shape, spacing, brick, "nearest", step)
    grid = brick_grid(shape, brick)
    indices = [tuple(int(i) for i in idx) for idx in indices]
    wanted = np.zeros(int(np.prod(grid)), bool)
    for bz, by, bx in indices:
        wanted[(bz * grid[1] + by) * grid[2] + bx] = True
    full = np.array(shape[::-1], np.int64)  # (i, j, k) order
    bsize = np.array(brick[::-1], np.int64)
    # Per brick number: the local array's strides and the offset of its first voxel, so that a
    # voxel's local index is iz·syx + iy·sx + ix − off (edge bricks are smaller).
    bi = np.indices(grid).reshape(3, -1)  # (bz, by, bx) of every brick number
    first = bi[::-1].T * bsize  # (n, 3): i, j, k of each brick's first voxel
    size = np.minimum(bsize, full - first)
    sx, syx = size[:, 0], size[:, 0] * size[:, 1]
    off = first[:, 2] * syx + first[:, 1] * sx + first[:, 0]
    # The group's box, as brick_weights' region of influence for nearest sampling.
    bounds = [_bounds(shape, brick, idx) for idx in indices]
    v0 = np.array([min(b[a][0] for b in bounds) for a in (2, 1, 0)], np.int64)
    v1 = np.array([max(b[a][1] for b in bounds) for a in (2, 1, 0)], np.int64)
    lo = np.where(v0 == 0, -np.inf, v0 - 0.5)
    hi = np.where(v1 == full, np.inf, v1 - 0.5)
    ray_ids, ka, counts = _clip_rays(rays, sp, step, lo, hi)
    xp = array_namespace(ray_ids)  # the rays' namespace: numpy, or CuPy on a GPU worker
    wanted_x, sx, syx, off = (xp.asarray(a) for a in (wanted, sx, syx, off))
    every = bool(wanted.all())
    runs = []
    csum = np.concatenate(([0], np.cumsum(to_host(counts))))  # chunk bounds: a host array per ray
    start, n_rays = 0, int(ray_ids.shape[0])
    while start < n_rays:
        end = max(int(np.searchsorted(csum, csum[start] + _CHUNK_SAMPLES, side="right")) - 1, start + 1)
        r, k = expand_samples(ray_ids[start:end], ka[start:end], counts[start:end])
        idx = nearest_voxels(sample_positions(rays, r, k, sp, step), shape)  # (m, 3): i, j, k
        ix, iy, iz = idx[:, 0], idx[:, 1], idx[:, 2]
        bnum = (iz // int(bsize[2]) * grid[1] + iy // int(bsize[1])) * grid[2] + ix // int(bsize[0])
        if not every:
            keep = xp.take(wanted_x, bnum)
            r, ix, iy, iz, bnum = r[keep], ix[keep], iy[keep], iz[keep], bnum[keep]
        local = iz * xp.take(syx, bnum) + iy * xp.take(sx, bnum) + ix - xp.take(off, bnum)
        # Runs of equal (ray, brick, voxel): one pair each, weighted by the run's length.
        m = int(r.shape[0])
        new = xp.concat(
            [xp.ones(min(m, 1), dtype=xp.bool), (r[1:] != r[:-1]) | (local[1:] != local[:-1]) | (bnum[1:] != bnum[:-1])]
        )
        at = xp.nonzero(new)[0]
        runs.append(
            (
                xp.take(r, at),
                xp.take(bnum, at),
                xp.take(local, at),
                xp.diff(xp.concat([at, xp.asarray([m], dtype=at.dtype)])),
            )
        )
        start = end
    if runs:
        r, bnum, local, weight = (xp.concat(list(x)) for x in zip(*runs))
    else:
        r = bnum = local = weight = xp.zeros(0, dtype=xp.int64)
    position = np.zeros(wanted.size, np.int64)
    for i, (bz, by, bx) in enumerate(indices):
        position[(bz * grid[1] + by) * grid[2] + bx] = i
    m = int(r.shape[0])
    row = xp.nonzero(xp.concat([xp.ones(min(m, 1), dtype=xp.bool), r[1:] != r[:-1]]))[0]
    return GroupRows(
        indices,
        rays.global_ids(xp.take(r, row)),
        xp.astype(xp.concat([row, xp.asarray([m], dtype=row.dtype)]), xp.int64),
        xp.take(xp.asarray(position), bnum),
        xp.astype(local, xp.int64),
        xp.astype(weight, xp.int64),
    )
