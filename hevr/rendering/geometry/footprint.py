"""Which pixels and tiles a brick can reach: its footprint on the image plane.

The client builds the render graph from footprints, in work proportional to
bricks + pixels (never bricks × pixels): each brick's box is projected once, and the tiles
it may touch are read off the projected rectangle.

Region of influence. A sample p (voxel-index space) gives weight to a voxel of brick
``[v0, v1)`` (per axis) only if p lies in ``[v0 − 1, v1]``: nearest sampling takes
``floor(p + 0.5)`` (so p ∈ [v0 − 0.5, v1 − 0.5)), trilinear sampling the corners
``floor(p)`` and ``floor(p) + 1`` (so p ∈ (v0 − 1, v1)); samples lie in the voxel-centre box
up to a 1e-9 relative tolerance, so clamping at the volume border moves an index by less
than that. The brick's *grown box* ``[v0 − 1, v1]`` (world units: times the spacing) thus
holds every sample that can touch the brick.

Projection. With camera basis (d, right, up) and a point's coordinates
``x = (p − position)·right``, ``y = (p − position)·up``, ``z = (p − position)·d``:

* parallel: the ray of image coordinates (u, v) passes through p iff
  ``x = parallel_scale·u`` and ``y = parallel_scale·v``; the map is linear, so the grown
  box's image is inside the rectangle of its 8 projected corners;
* perspective: the ray through p has ``u = x/(z·tan(angle/2))``, ``v = y/(…)`` for
  ``z > 0``; a central projection maps a convex set in ``z > 0`` onto the convex hull of its
  corners' images, so again the corner rectangle bounds it. Samples have ``t >= 0``, hence
  ``z >= 0``: a box with every corner at ``z < 0`` is never sampled; a box that reaches
  ``z <= 0`` (the camera inside or beside it) gets the whole image;
* slice plane (:class:`~hevr.rendering.geometry.plane.Plane`): pixel (r, c)'s samples are
  ``origin + c·du·u + r·dv·v + s·n`` for the slab's offsets s; the map to (c, r) is linear
  (:func:`_plane_extent`), and a box whose extent along n misses the slab is never sampled.

Camera pixel (r, c) has ``u = ((c + 0.5)/W·2 − 1)·aspect`` and ``v = 1 − (r + 0.5)/H·2``; the
rectangle is widened by one pixel on every side against rounding. Bricks whose rectangle
holds no hit pixel (2-D prefix sums of the hit mask, O(1) per brick) get no task.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...image.tiles import TileLayout
from .camera import Camera
from .plane import Plane

__all__ = ["Footprint", "brick_footprints"]


@dataclass(frozen=True)
class Footprint:
    """A brick's conservative image rectangle and the tiles it overlaps.

    Attributes
    ----------
    rect : (r0, r1, c0, c1)
        Pixel rows ``[r0, r1)`` and columns ``[c0, c1)``; every pixel whose ray can touch the
        brick lies inside.
    tiles : tuple of int
        Tiles (:class:`hevr.image.tiles.TileLayout` numbering) overlapping the rectangle that hold
        a hit pixel inside it, ascending.
    """

    rect: tuple[int, int, int, int]
    tiles: tuple[int, ...]

    def bands(self, tile: int, tiles_x: int) -> list[Footprint]:
        """The footprint cut into tile rows: one piece per tile row that holds some of its tiles.

        >>> [(f.rect, f.tiles) for f in Footprint((1, 5, 0, 2), (0, 2)).bands(2, 2)]
        [((1, 2, 0, 2), (0,)), ((2, 4, 0, 2), (2,))]
        """
        r0, r1, c0, c1 = self.rect
        out = []
        for ty in range(r0 // tile, (r1 - 1) // tile + 1):
            tiles = tuple(t for t in self.tiles if t // tiles_x == ty)
            if tiles:
                out.append(Footprint((max(r0, ty * tile), min(r1, (ty + 1) * tile), c0, c1), tiles))
        return out

    def pixels(self, width: int) -> np.ndarray:
        """Global pixel indices of the rectangle, ascending.

        >>> Footprint((1, 3, 0, 2), (0,)).pixels(4).tolist()
        [4, 5, 8, 9]
        """
        r0, r1, c0, c1 = self.rect
        return (np.arange(r0, r1, dtype=np.int64)[:, None] * width + np.arange(c0, c1, dtype=np.int64)[None, :]).ravel()


def _grown_boxes(
    shape: tuple[int, int, int], spacing, brick: tuple[int, int, int], bricks: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World-space corners lo, hi (B, 3) of each brick's grown box (x, y, z order)."""
    b = np.asarray(brick[::-1], np.float64)  # (bx, by, bz)
    n = np.asarray(shape[::-1], np.float64)
    idx = bricks[:, ::-1].astype(np.float64)  # (i, j, k) brick coordinates
    v0 = idx * b
    v1 = np.minimum((idx + 1) * b, n)
    sp = np.asarray(spacing, np.float64)
    return (v0 - 1.0) * sp, v1 * sp


def brick_footprints(
    camera: Camera | Plane,
    shape: tuple[int, int, int],
    spacing,
    brick: tuple[int, int, int],
    hit: np.ndarray,
    tile: int,
) -> dict[tuple[int, int, int], Footprint]:
    """Footprints of every brick whose rectangle holds a hit pixel, in brick raster order.

    Parameters
    ----------
    camera : Camera or Plane
        A plane's projection is linear (:func:`_plane_extent`); bricks its slab misses get no task.
    shape : (nz, ny, nx)
    spacing : (sx, sy, sz)
    brick : (B0, B1, B2)
        Brick shape in array order.
    hit : (H*W,) bool
        Which pixels' rays hit the volume (``n_samples > 0``).
    tile : int
        Tile edge of the reduce.

    Examples
    --------
    >>> cam = Camera((1, 1, 9), (1, 1, 0), width=4, height=4, parallel=True, parallel_scale=2)
    >>> fp = brick_footprints(cam, (4, 4, 4), (1, 1, 1), (2, 2, 2), np.ones(16, bool), 2)
    >>> len(fp), fp[(0, 0, 0)].tiles
    (8, (0, 1, 2, 3))
    """
    H, W = camera.height, camera.width
    grid = tuple(-(-s // b) for s, b in zip(shape, brick))
    bricks = np.array(list(np.ndindex(*grid)), dtype=np.int64).reshape(-1, 3)
    lo, hi = _grown_boxes(shape, spacing, brick, bricks)
    sel = np.array([[(c >> a) & 1 for a in range(3)] for c in range(8)], bool)  # (8, 3)
    corners = np.where(sel[None], hi[:, None, :], lo[:, None, :])  # (B, 8, 3)
    if isinstance(camera, Plane):
        cmin, cmax, rmin, rmax, behind = _plane_extent(camera, corners)
        whole = np.zeros(len(bricks), bool)
    else:
        cmin, cmax, rmin, rmax, behind, whole = _camera_extent(camera, corners)
    with np.errstate(invalid="ignore"):
        c0 = np.clip(np.floor(cmin) - 1, 0, W).astype(np.int64)
        c1 = np.clip(np.ceil(cmax) + 2, 0, W).astype(np.int64)
        r0 = np.clip(np.floor(rmin) - 1, 0, H).astype(np.int64)
        r1 = np.clip(np.ceil(rmax) + 2, 0, H).astype(np.int64)
    c0, c1, r0, r1 = (np.where(whole, full, a) for a, full in ((c0, 0), (c1, W), (r0, 0), (r1, H)))
    # Prefix sums of the hit mask: hits in any rectangle in O(1).
    S = np.zeros((H + 1, W + 1), np.int64)
    S[1:, 1:] = hit.reshape(H, W).cumsum(0).cumsum(1)

    def hits(a0, a1, b0, b1):
        return S[a1, b1] - S[a0, b1] - S[a1, b0] + S[a0, b0]

    live = ~behind & (r1 > r0) & (c1 > c0)
    live[live] = hits(r0[live], r1[live], c0[live], c1[live]) > 0
    lay = TileLayout(W, H, tile)
    out: dict[tuple[int, int, int], Footprint] = {}
    for i in np.flatnonzero(live).tolist():
        a0, a1, b0, b1 = int(r0[i]), int(r1[i]), int(c0[i]), int(c1[i])
        tys = np.arange(a0 // tile, (a1 - 1) // tile + 1)
        txs = np.arange(b0 // tile, (b1 - 1) // tile + 1)
        ty, tx = (a.ravel() for a in np.meshgrid(tys, txs, indexing="ij"))
        q0, q1 = np.maximum(ty * tile, a0), np.minimum((ty + 1) * tile, a1)
        p0, p1 = np.maximum(tx * tile, b0), np.minimum((tx + 1) * tile, b1)
        keep = hits(q0, q1, p0, p1) > 0
        bz, by, bx = (int(k) for k in bricks[i])
        out[bz, by, bx] = Footprint((a0, a1, b0, b1), tuple((ty[keep] * lay.tiles_x + tx[keep]).tolist()))
    return out


def _camera_extent(camera: Camera, corners: np.ndarray) -> tuple[np.ndarray, ...]:
    """Column and row ranges (fractional pixel indices) of the projected grown boxes (B, 8, 3),
    which boxes lie behind the camera and which reach its plane (then: the whole image)."""
    d, right, up = camera.basis()
    rel = corners - np.asarray(camera.position, np.float64)
    x, y, z = rel @ right, rel @ up, rel @ d  # (B, 8)
    behind = (z < 0).all(axis=1)
    if camera.parallel:
        assert camera.parallel_scale is not None  # Camera.__post_init__ sets it for every camera
        scale = float(camera.parallel_scale)
        u, v = x / scale, y / scale
        whole = np.zeros(len(corners), bool)
    else:
        eps = 1e-9 * max(float(np.abs(rel).max()), 1.0)
        whole = (z <= eps).any(axis=1) & ~behind
        with np.errstate(divide="ignore", invalid="ignore"):
            zz = np.where(z > eps, z, 1.0) * camera.tan_half
            u, v = x / zz, y / zz
    H, W = camera.height, camera.width
    aspect = W / H
    cmin = (u.min(axis=1) / aspect + 1.0) * W / 2.0 - 0.5
    cmax = (u.max(axis=1) / aspect + 1.0) * W / 2.0 - 0.5
    rmin = (1.0 - v.max(axis=1)) * H / 2.0 - 0.5
    rmax = (1.0 - v.min(axis=1)) * H / 2.0 - 0.5
    return cmin, cmax, rmin, rmax, behind, whole


def _plane_extent(plane: Plane, corners: np.ndarray) -> tuple[np.ndarray, ...]:
    """A plane's column and row ranges of the grown boxes (B, 8, 3), and which boxes its slab misses.

    A point X = origin + c·du·u + r·dv·v + s·n (n orthogonal to u and v) has
    ``a = (X - origin)·u = c·du + g·r·dv`` and ``b = (X - origin)·v = g·c·du + r·dv``
    (g = u·v, |g| <= 1e-6), so ``c·du = (a - g·b)/(1 - g²)`` and ``r·dv = (b - g·a)/(1 - g²)``:
    a linear map, so the box's pixels lie in its corners' rectangle. The slab reaches only
    points with s in [s_first, s_last]; a box whose s range misses it gets no task.
    """
    u, v, n = plane.basis()
    rel = corners - np.asarray(plane.origin, np.float64)
    a, b, s = rel @ u, rel @ v, rel @ n  # (B, 8)
    g = float(u @ v)
    du, dv = plane.pixel_spacing
    c = (a - g * b) / (1.0 - g * g) / du
    r = (b - g * a) / (1.0 - g * g) / dv
    offsets = plane.slab_offsets
    eps = 1e-9 * max(float(np.abs(rel).max()), float(offsets[-1] - offsets[0]), 1.0)
    missed = (s.max(axis=1) < offsets[0] - eps) | (s.min(axis=1) > offsets[-1] + eps)
    return c.min(axis=1), c.max(axis=1), r.min(axis=1), r.max(axis=1), missed
