"""Gradient-magnitude modulation (the paper's future work, §Conclusions): a channel of g·e(d).

Definition. With the volume's normalised densities ``d = normalize_density(v, value_range)``
in [0, 1] (as for the vector channel) and its world-order spacing ``(sx, sy, sz)``:

* ``∇d`` by central differences in **world units**: ``np.gradient(d, sz, sy, sx)`` —
  ``(d[i+1] − d[i−1]) / 2s`` inside, one-sided ``(d[1] − d[0]) / s`` and
  ``(d[−1] − d[−2]) / s`` at the volume's faces; an axis of a single voxel contributes 0;
* ``m = |∇d| = sqrt(∂z² + ∂y² + ∂x²)`` per voxel;
* ``g = m / max(m)`` over the **whole volume**, in [0, 1] (``g = 0`` everywhere when
  ``max(m) = 0``, a constant volume);
* the channel holds ``G = g · e(d)`` per voxel, ``e`` the Alg. 4 encoding
  (:func:`hevr.volume.density.encode_density`): k components in [0, 1], stored like the
  vector channel, ``round(G_j · 10^digits)`` with exponent ``−digits`` (same k and digits).

Rendering. ``mode="emphasize"`` or ``"tf"`` with ``gradient=True`` reads this channel instead
of the vector channel, with the same combination matrix and kernel: a sample contributes
``g · dot(e(d), e(density))`` (emphasis) or ``g · Σ_i dot(e(d), e(d_i)) c_i`` (transfer
function), so homogeneous regions (``g = 0``) vanish and boundaries, where the density changes
fastest, stand out. Everything is linear in the stored vector, which is why the server
needs nothing but the stored products: it sums them exactly as it sums ``e(d)``.

What stays with the owner. ``max(m)`` is derived from the plaintext: it is used only by the
data owner's encryption tasks and is **never stored** (neither in the store's metadata nor in a
Dask key; a resume recomputes it). The channel costs **k more ciphertexts per voxel**
(docs/format.md).

Bricks. A volume encrypted in bricks still uses the whole volume's gradient: each brick's
``∇d`` is computed from the brick plus a one-voxel halo of its neighbours (central differences
across brick faces, one-sided only at the volume's faces), and ``max(m)`` in a first pass over
every brick, so memory stays a few bricks whatever the volume's size (numpy, memmap or dask
input alike) and every voxel gets exactly the value the whole array gives.

>>> d = np.array([[[0.0, 0.0, 1.0, 1.0]]])                 # one row along x
>>> gradient_magnitude(d, (1.0, 1.0, 1.0)).ravel().tolist()
[0.0, 0.5, 0.5, 0.0]
>>> G = gradient_encoding(np.array([[[0, 0, 255, 255]]], dtype=np.uint8), (1, 1, 1), (0, 255), 2)
>>> G.round(3).tolist()                                     # g = 1 at the edge, 0 in the flat parts
[[[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]]]
>>> halo_of((0, 1, 2), (1, 3, 3))
((0, 0), (1, 1), (1, 0))
"""

from __future__ import annotations

from typing import Any

import dask
import numpy as np

from ..core.validate import check_spacing
from .density import encode_density, normalize_density

__all__ = ["brick_gradient_encoding", "gradient_encoding", "gradient_magnitude", "halo_of", "max_gradient_magnitude"]

Halo = tuple[tuple[int, int], tuple[int, int], tuple[int, int]]
NO_HALO: Halo = ((0, 0), (0, 0), (0, 0))


def halo_of(index: Any, grid: Any) -> Halo:
    """Halo voxels (before, after) per axis of brick ``index`` in a grid of ``grid`` bricks:
    one on every side with a neighbour, none at the volume's faces (Dask's
    ``overlap(depth=1, boundary="none")`` gives exactly these blocks)."""
    return tuple((int(i > 0), int(i < g - 1)) for i, g in zip(index, grid))  # type: ignore[return-value]


def gradient_magnitude(d: np.ndarray, spacing: Any, halo: Halo = NO_HALO) -> np.ndarray:
    """``|∇d|`` (module docstring) of the inner voxels of ``d``, a block with ``halo`` voxels
    (before, after) per axis around them; float64 of the inner block's shape."""
    sx, sy, sz = check_spacing(spacing)
    d = np.asarray(d, dtype=np.float64)
    total = np.zeros(d.shape, dtype=np.float64)
    for axis, s in enumerate((sz, sy, sx)):
        if d.shape[axis] >= 2:  # a single voxel along an axis has no difference along it
            g = np.gradient(d, s, axis=axis)
            total += g * g
    inner = tuple(slice(lo, n - hi) for (lo, hi), n in zip(halo, d.shape))
    return np.sqrt(total[inner])


def brick_gradient_encoding(
    block: np.ndarray, halo: Halo, spacing: Any, value_range: Any, dims: int, m_max: float
) -> np.ndarray:
    """``G = g·e(d)`` of a brick's voxels, float64 (bz, by, bx, k), from the brick with its
    ``halo`` and the whole volume's ``m_max`` (the owner's; ``0``: G = 0)."""
    d = normalize_density(block, value_range)
    m = gradient_magnitude(d, spacing, halo)
    inner = d[tuple(slice(lo, n - hi) for (lo, hi), n in zip(halo, d.shape))]
    g = m / m_max if m_max > 0 else np.zeros_like(m)
    return g[..., None] * encode_density(inner, dims)


def gradient_encoding(vol: Any, spacing: Any, value_range: Any, dims: int) -> np.ndarray:
    """``G = g·e(d)`` of a whole (in-memory) volume, float64 (nz, ny, nx, k): the definition
    the writer stores (before quantisation) and :func:`hevr.render_plain` renders."""
    vol = np.asarray(vol)
    m = gradient_magnitude(normalize_density(vol, value_range), spacing)
    top = float(m.max()) if m.size else 0.0
    return brick_gradient_encoding(vol, NO_HALO, spacing, value_range, dims, top)


def _brick_max(block: np.ndarray, halo: Halo, spacing: Any, value_range: Any) -> float:
    m = gradient_magnitude(normalize_density(block, value_range), spacing, halo)
    return float(m.max()) if m.size else 0.0


def max_gradient_magnitude(haloed: np.ndarray, grid: Any, spacing: Any, value_range: Any, run: Any, tag: str) -> float:
    """The whole volume's ``max(m)``, one task per haloed brick (``haloed``: the grid of Dask
    delayed blocks, bricks with their one-voxel halo). ``run(tasks)`` computes the tasks (the
    writer's scheduler and progress); ``tag`` is a random token for the task names — keys never
    carry a value derived from the plaintext. The result stays in the owner's process."""
    task = dask.delayed(_brick_max, pure=False)
    tasks = [
        task(
            haloed[idx],
            halo_of(idx, grid),
            spacing,
            value_range,
            dask_key_name=f"hevr-gradient-max-{tag}-{idx[0]}-{idx[1]}-{idx[2]}",
        )
        for idx in np.ndindex(*haloed.shape)
    ]
    return max(run(tasks), default=0.0)
