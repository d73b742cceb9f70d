"""The client's half of a verified render's check: Σ_{r,k} ρ_{r,k}·B_{r,k} from the public geometry.

B_{r,k} = Σ_v w_{r,v}·β_{v,k} is what a ray's tag sum holds beside α times its value sum
(:mod:`hevr.rendering.verify`); the key holder recomputes it from the view, brick by brick, with the
same weights the map tasks use (:func:`~hevr.rendering.geometry.weights.brick_weights`) and the β of
the voxels the rays reach (the PRF, :func:`hevr.crypto.tags.betas`, and for a pyramid level
:func:`level_betas`).
"""

from __future__ import annotations

import dataclasses
import os
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np

from ..crypto.tags import betas, coefficients_at, tag_key_of, weighted_beta_total
from ..store.pyramid import LEVEL_FACTOR
from ..volume.pyramid import level_shape
from .geometry.footprint import brick_footprints
from .geometry.rays import RaySet
from .geometry.weights import brick_bounds, brick_weights

if TYPE_CHECKING:
    from .verification import Verification

__all__ = ["beta_sum", "footprint_rays", "level_betas"]

_CHILDREN = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)])  # z, y, x offsets of 8 children


def level_betas(
    key: Any,
    store_id: str,
    channel: str,
    component: int,
    level: int,
    voxels: Any,
    base_shape: tuple,
    cache: dict | None = None,
) -> np.ndarray:
    """β of the flat voxel indices ``voxels`` of pyramid ``level`` as ``(len, nl)`` uint32 limbs: the
    level's tags are built as its values are (:mod:`hevr.store.pyramid`), 125 ⊗ the product of the 8
    children's (clamped at the far edges, as there), so β_L(v) = 125·Σ β_{L−1}(child), down to level
    0's PRF values — in numpy, in 16-bit pieces with carries (``cache`` as for :func:`betas`).

    >>> from hevr.crypto.tags import TagKey
    >>> k = TagKey(1, bytes(32), 2**200)
    >>> as_int = lambda a: [int.from_bytes(r.astype("<u4").tobytes(), "little") for r in a]
    >>> b0 = as_int(level_betas(k, "s", "scalar", 0, 0, range(8), (2, 2, 2)))
    >>> as_int(level_betas(k, "s", "scalar", 0, 1, [0], (2, 2, 2))) == [125 * sum(b0)]
    True
    >>> as_int(level_betas(k, "s", "scalar", 0, 1, [0], (1, 1, 1))) == [125 * 8 * b0[0]]  # itself 8 times
    True
    """
    v = np.asarray(voxels, dtype=np.int64).reshape(-1)
    if level == 0:
        return betas(key, store_id, channel, 0, component, v, cache)
    shape, below = level_shape(base_shape, level), level_shape(base_shape, level - 1)
    zyx = np.stack(np.unravel_index(v, shape), axis=1)
    kids = np.minimum(zyx[:, None, :] * 2 + _CHILDREN[None], np.asarray(below) - 1).reshape(-1, 3)
    uniq, inverse = np.unique(np.ravel_multi_index(tuple(kids.T), below), return_inverse=True)
    sub = level_betas(key, store_id, channel, component, level - 1, uniq, base_shape, cache)
    pieces = np.ascontiguousarray(sub, dtype="<u4").view("<u2").astype(np.uint64)  # (U, P), each < 2^16
    x = pieces[inverse.reshape(-1, 8)].sum(axis=1) * np.uint64(LEVEL_FACTOR)  # < 8·125·2^16 < 2^26
    cols = [x[:, j] for j in range(x.shape[1])]
    j = 0
    while j < len(cols):  # carries into 16-bit pieces, as many as needed
        carry = cols[j] >> np.uint64(16)
        cols[j] = cols[j] & np.uint64(0xFFFF)
        if carry.any():
            if j + 1 == len(cols):
                cols.append(np.zeros_like(carry))
            cols[j + 1] = cols[j + 1] + carry
        j += 1
    if len(cols) % 2:
        cols.append(np.zeros_like(cols[0]))
    out = np.stack(cols, axis=1).astype("<u2")
    return np.ascontiguousarray(out).view("<u4")


def footprint_rays(rays: RaySet, rect: tuple, hit: np.ndarray) -> RaySet:
    """The hit rays of the pixel rectangle ``rect`` (rows ``[r0, r1)``, columns ``[c0, c1)``) as a
    subset of ``rays`` (global pixel ids kept): what a map task casts for its brick, so its weights
    are the same (every ray's geometry is computed elementwise)."""
    if rays.pixel_ids is not None:  # already a subset: as it is
        return rays
    r0, r1, c0, c1 = rect
    W = rays.width
    ids = (np.arange(r0, r1)[:, None] * W + np.arange(c0, c1)[None, :]).reshape(-1)
    ids = ids[hit[ids]]
    return dataclasses.replace(
        rays,
        origins=rays.origins[ids],
        directions=rays.directions[ids],
        t_enter=rays.t_enter[ids],
        t_exit=rays.t_exit[ids],
        n_samples=rays.n_samples[ids],
        pixel_ids=ids,
        t_index=None if rays.t_index is None else rays.t_index[ids],
    )


def beta_sum(record: Verification, private_key: Any, rays: RaySet) -> int:
    """Σ_{r,k} ρ_{r,k}·B_{r,k} mod n of the verified view ``record`` from its public geometry and the
    PRF (module docstring): brick by brick, on a thread per core (the geometry's numpy work releases
    the GIL); ``rays`` are the view's."""
    key = tag_key_of(private_key)
    cache: dict = {}  # β blocks shared by neighbouring bricks (a race only recomputes a block)
    # the bricks whose footprint holds a hit pixel (O(bricks + pixels), as the render graph picks its
    # map tasks): a superset of the touched ones, whose extra bricks add nothing (empty weights)
    hit = np.asarray(rays.n_samples) > 0
    prints = brick_footprints(
        record.camera, record.shape, record.spacing, record.brick, hit, max(record.camera.width, record.camera.height)
    )
    with ThreadPoolExecutor(max_workers=max(1, min(os.cpu_count() or 1, 8))) as pool:
        parts = list(
            pool.map(
                lambda item: _brick_beta_sum(record, key, footprint_rays(rays, item[1].rect, hit), item[0], cache),
                prints.items(),
            )
        )
    return sum(parts) % record.n


def _brick_beta_sum(record: Verification, key: Any, rays: RaySet, index: tuple, cache: dict) -> int:
    """Σ_{r,k} ρ_{r,k}·B_{r,k} over the rays of one brick (``index``)."""
    K = record.components
    r = record
    bw = brick_weights(rays, r.shape, r.spacing, r.brick, index, r.sampling, r.step, r.digits)
    if not bw.rays.size:
        return 0
    _, ny, nx = record.shape
    (z0, z1), (y0, y1), (x0, x1) = brick_bounds(record.shape, record.brick, index)
    zz, yy, xx = np.meshgrid(np.arange(z0, z1), np.arange(y0, y1), np.arange(x0, x1), indexing="ij")
    used, local = np.unique(bw.voxels, return_inverse=True)  # β of the voxels the rays reach only
    glob = ((zz * ny + yy) * nx + xx).reshape(-1)[used]
    rho = coefficients_at(record.seed, (bw.rays[:, None] * K + np.arange(K)).reshape(-1)).reshape(-1, K)
    total = 0
    for k in range(K):
        beta = level_betas(key, record.store_id, record.channel, k, record.level, glob, record.base_shape, cache)
        total += weighted_beta_total(beta, bw.indptr, local.reshape(-1), bw.weights, rho[:, k])
    return total
