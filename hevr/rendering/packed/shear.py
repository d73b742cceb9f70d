"""Shear-warp geometry of a parallel view: slices, one sample per slice, and the warp to pixels.

All in array index space (voxel (u0, u1, u2) = (k, j, i) at world (i·sx, j·sy, k·sz)). A parallel
camera's direction d becomes d_idx = (d_z/sz, d_y/sy, d_x/sx). The *principal* axis ``p`` is the
one with the largest |d_idx| (Lacroute & Levoy 1994); the other two are ``a`` (a packed store's
packing axis) and ``b``. Slice k (u_p = k, k = 0 … N_p − 1) is sampled once per ray. The rays of
the *intermediate image* are indexed by integers (i, j): ray (i, j) passes through
(u_a, u_b) = (i, j) on slice 0 and has the view's direction, so it meets slice k at

    (i + c_a(k), j + c_b(k)),     c(k) = k·s,  s_a = d_a/d_p, s_b = d_b/d_p,  |s| ≤ 1.

The ray one step further along ``a`` meets every slice one voxel further along ``a`` with the same
fractional offset: the lattice a packed store's products exploit (:mod:`hevr.rendering.packed.plan`).
X-ray sums do not depend on the order of the slices, so the sign of d_p does not matter.

Samples (``nearest``: the voxel at floor(x + 0.5) per axis; ``trilinear``, which on a packed store
means *bilinear within the slice*: the 2×2 voxels around the point, zero outside the volume).
A ray's sample count n(i, j) is the number of slices whose sample reads a voxel (nearest) or lies
in the closed box [0, n_a − 1] × [0, n_b − 1] (bilinear); its X-ray value is Σ / n (0 when n = 0).

The rays along ``b`` need not be integers (only ``a`` is the packs' lattice): they are spaced as
the camera's pixels where those are further apart than the voxels (a zoomed-out view computes no
more rays than it has pixels), else one voxel apart.

The warp: the camera's pixel ray meets slice 0 at real (i*, j*) (:meth:`ShearGeometry.pixel_coords`);
its value is the bilinear interpolation of the intermediate image there, rays outside the image
counting 0 (:meth:`ShearGeometry.warp`). Only the rays the camera's pixels need are computed.

A view's plan is sized by its slices and rays: :func:`check_plan_size` refuses one too big before any
table per slice is allocated.

>>> from hevr.rendering.geometry.camera import Camera
>>> cam = Camera.orbit((8, 8, 8), azimuth=90, width=4, height=4, parallel=True)   # from +x
>>> g = ShearGeometry.of(cam, (8, 8, 8), (1, 1, 1), axis=0)
>>> g.principal, g.other, g.slices, round(g.slope_a, 6), round(g.slope_b, 6)
(2, 1, 8, 0.0, 0.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.limits import render_limits
from ...errors import ParameterError, RenderPlanError

__all__ = ["AXIS_NAMES", "MAX_PLAN_CELLS", "ShearGeometry", "check_plan_size"]

AXIS_NAMES = ("z", "y", "x")
_WORLD = (2, 1, 0)  # array axis -> index of its world coordinate (x, y, z)


def _row_step(ic: np.ndarray, jc: np.ndarray, width: int, height: int) -> float:
    """Δ: the rows' spacing along ``b``, the pixels' (the shorter of the steps to the next column and
    to the next row, in voxels on slice 0), at least 1: rays no closer than the pixels need, nor
    than the voxels.

    >>> _row_step(np.array([0.0, 1.5, 0.0, 1.5]), np.array([0.0, 0.0, 2.5, 2.5]), 2, 2)
    1.5
    """
    steps = []
    if width > 1:
        steps.append(math.hypot(float(ic[1] - ic[0]), float(jc[1] - jc[0])))
    if height > 1:
        steps.append(math.hypot(float(ic[width] - ic[0]), float(jc[width] - jc[0])))
    return max(1.0, min(steps)) if steps else 1.0


def index_vector(v: Any, spacing: Any) -> np.ndarray:
    """A world vector (x, y, z) in array index units (u0, u1, u2) = (z/sz, y/sy, x/sx).

    >>> index_vector((1.0, 2.0, 3.0), (1.0, 2.0, 0.5)).tolist()
    [6.0, 1.0, 1.0]
    """
    v = np.asarray(v, dtype=np.float64)
    sp = np.asarray(spacing, dtype=np.float64)
    return np.stack([v[..., _WORLD[ax]] / sp[_WORLD[ax]] for ax in range(3)], axis=-1)


@dataclass(frozen=True)
class ShearGeometry:
    """The slices, slopes and intermediate rays of one parallel view of a volume (module docstring).

    Attributes
    ----------
    shape : (int, int, int)
        The volume's array shape.
    spacing : (float, float, float)
        Its voxel spacing, world order (sx, sy, sz).
    axis, principal, other : int
        The array axes ``a`` (packing), ``p`` (slices) and ``b``.
    slope_a, slope_b : float
        s_a, s_b: the in-slice shift per slice.
    i_range : (int, int)
        The intermediate rays computed along ``a``, ``[lo, hi)`` (integers: the packs' lattice).
    rows : (float, float, int)
        Along ``b``: the first ray's position, the spacing Δ and the count: rays at
        j_r = j_0 + r·Δ (:meth:`row_positions`), Δ = 1 or, where the camera's pixels are further
        apart than the voxels, their spacing. Only rays that touch the volume and that the pixels
        need are computed.
    """

    shape: tuple[int, int, int]
    spacing: tuple[float, float, float]
    axis: int
    principal: int
    other: int
    slope_a: float
    slope_b: float
    i_range: tuple[int, int]
    rows: tuple[float, float, int]

    @classmethod
    def of(cls, camera: Any, shape: Any, spacing: Any, axis: int) -> ShearGeometry:
        """The geometry of ``camera`` (parallel) on a volume of ``shape`` and ``spacing`` packed along
        ``axis``, which must not be the view's principal axis (a view within 45° of it is refused
        with a :class:`hevr.ParameterError` saying which views the store serves)."""
        shape = tuple(int(s) for s in shape)
        spacing = tuple(float(s) for s in spacing)
        if not getattr(camera, "parallel", False):
            raise ParameterError(
                "camera: expected a parallel camera (parallel=True) for the packed store, got a perspective one: a "
                "packed store renders parallel projections slice by slice; pass hevr.Camera.orbit(..., parallel=True), "
                "or render a per-voxel store (encrypt_volume(..., layout='voxel')) for perspective views"
            )
        d = index_vector(camera.basis()[0], spacing)
        mag = np.abs(d)
        p = max((ax for ax in range(3) if ax != axis), key=lambda ax: (mag[ax], -ax))
        if mag[axis] > mag[p]:
            name = AXIS_NAMES[axis]
            raise ParameterError(
                f"camera: expected a view whose principal axis is not the packing axis {axis} ({name}) of this "
                f"packed store, got a view within 45° of the {name} axis: the store serves parallel views whose "
                f"direction leans more towards the other two axes than towards {name} (orbits around the {name} "
                f"axis: with a store packed along z, Camera.orbit(..., parallel=True) at azimuth 90 or a view "
                "'anterior', 'posterior', 'left' or 'right' within 45°); for views along it encrypt a store packed "
                f"along another axis (pack_axis=...) or a per-voxel store (layout='voxel')"
            )
        if mag[p] == 0:  # pragma: no cover - the camera's direction is a unit vector
            raise ParameterError("camera: expected a view direction, got a zero vector")
        a = axis
        b = 3 - p - a
        sa, sb = float(d[a] / d[p]) + 0.0, float(d[b] / d[p]) + 0.0  # + 0.0: no -0.0
        geo = cls(shape, spacing, a, p, b, sa, sb, (0, 0), (0.0, 1.0, 0))
        i_rng, j_rng = geo._touching()
        ic, jc = geo.pixel_coords(camera)
        # only the rays the pixels interpolate between
        i_rng = (max(i_rng[0], math.floor(float(ic.min()))), min(i_rng[1], math.floor(float(ic.max())) + 2))
        i_rng = (i_rng[0], max(i_rng))
        step = _row_step(ic, jc, camera.width, camera.height)
        j0 = float(math.floor(max(j_rng[0], float(jc.min()))))
        top = min(float(j_rng[1] - 1), float(jc.max()))
        count = max(0, math.floor((top - j0) / step) + 2) if top >= j0 else 0
        return cls(shape, spacing, a, p, b, sa, sb, i_rng, (j0, step, count))

    # -- slices and rays ------------------------------------------------------------------
    @property
    def slices(self) -> int:
        """N_p, the slices (samples per ray at most)."""
        return self.shape[self.principal]

    @property
    def size(self) -> tuple[int, int]:
        """(N_i, N_j): the intermediate image's rays along ``a`` and ``b``."""
        return self.i_range[1] - self.i_range[0], self.rows[2]

    def row_positions(self) -> np.ndarray:
        """j_r = j_0 + r·Δ of every row of rays, float64 (the one expression every user of rows takes)."""
        j0, step, count = self.rows
        return j0 + np.arange(count, dtype=np.float64) * step

    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """(c_a(k), c_b(k)) for every slice k, float64."""
        k = np.arange(self.slices, dtype=np.float64)
        return k * self.slope_a, k * self.slope_b

    def _touching(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """The rays with a sample in (−1, n) along both axes for some slice: i + c(k) ∈ (−1, n_a)."""
        out = []
        for slope, n in ((self.slope_a, self.shape[self.axis]), (self.slope_b, self.shape[self.other])):
            end = (self.slices - 1) * slope
            lo, hi = min(0.0, end), max(0.0, end)
            out.append((math.floor(-hi), math.ceil(n - lo)))
        return out[0], out[1]

    def in_slice(self, sampling: str) -> tuple[np.ndarray, np.ndarray]:
        """Per slice and ray, whether the sample counts along ``a`` and along ``b``: (N_p, N_i) and
        (N_p, N_j) bools (module docstring: the voxel exists, or the point lies in the closed box)."""
        ca, cb = self.offsets()
        out = []
        for c, pos, n in (
            (ca, np.arange(*self.i_range, dtype=np.float64), self.shape[self.axis]),
            (cb, self.row_positions(), self.shape[self.other]),
        ):
            x = pos[None, :] + c[:, None]
            out.append(
                (np.floor(x + 0.5) >= 0) & (np.floor(x + 0.5) < n) if sampling == "nearest" else (x >= 0) & (x <= n - 1)
            )
        return out[0], out[1]

    def sample_counts(self, sampling: str) -> np.ndarray:
        """n(i, j): the samples of every intermediate ray, (N_i, N_j) int64."""
        ina, inb = self.in_slice(sampling)
        return ina.astype(np.int64).T @ inb.astype(np.int64)

    # -- the warp -------------------------------------------------------------------------
    def pixel_coords(self, camera: Any) -> tuple[np.ndarray, np.ndarray]:
        """(i*, j*): where every pixel's ray (row-major) meets slice 0, in intermediate-image units."""
        origins, _ = camera.rays()
        o = index_vector(origins, self.spacing)
        d = index_vector(camera.basis()[0], self.spacing)
        t = -o[:, self.principal] / d[self.principal]
        return o[:, self.axis] + t * d[self.axis], o[:, self.other] + t * d[self.other]

    def warp(self, image: np.ndarray, coords: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Bilinear interpolation of the intermediate ``image`` (N_i, N_j) at the pixels' (i*, j*)
        (rays outside the image count 0); returns one value per pixel, float64."""
        ic, jc = coords
        img = np.asarray(image, dtype=np.float64)
        ni, nj = img.shape
        rj = (jc - self.rows[0]) / self.rows[1]  # in row units
        i0, j0 = np.floor(ic), np.floor(rj)
        fi, fj = ic - i0, rj - j0
        i0 = i0.astype(np.int64) - self.i_range[0]
        j0 = j0.astype(np.int64)
        out = np.zeros(ic.shape, dtype=np.float64)
        for di, wi in ((0, 1.0 - fi), (1, fi)):
            for dj, wj in ((0, 1.0 - fj), (1, fj)):
                ii, jj = i0 + di, j0 + dj
                ok = (ii >= 0) & (ii < ni) & (jj >= 0) & (jj < nj)
                out[ok] += (wi * wj)[ok] * img[ii[ok], jj[ok]]
        return out


MAX_PLAN_CELLS = 1 << 24  # slices × (rays along a + rows): the plan's tables (~80 bytes a cell, ~1.3 GB at most)


def check_plan_size(geo: ShearGeometry) -> None:
    """Refuse (:class:`hevr.RenderPlanError`) a plan whose tables would be too big: slices × (rays
    along the packing axis + rows) above :data:`MAX_PLAN_CELLS` (or the render sample limit), or an
    intermediate image above the pixel limit — what a store's metadata of millions of thin slices
    would ask, before anything is allocated per slice.

    >>> from hevr.rendering.geometry.camera import Camera
    >>> g = ShearGeometry.of(Camera.orbit((8, 8, 8), azimuth=90, width=4, height=4, parallel=True),
    ...                      (8, 8, 8), (1.0, 1.0, 1.0), axis=0)
    >>> check_plan_size(g) is None
    True
    """
    max_pixels, max_samples = render_limits()
    n_i, n_j = geo.size
    cells = int(geo.slices) * (int(n_i) + int(n_j))
    if cells > min(MAX_PLAN_CELLS, max_samples) or int(n_i) * int(n_j) > max_pixels:
        raise RenderPlanError(
            f"camera: expected a packed frame whose plan fits (slices × (rays + rows) at most "
            f"{min(MAX_PLAN_CELLS, max_samples)}, rays × rows at most {max_pixels}), got "
            f"{geo.slices} slices, {n_i} rays and {n_j} rows for the store's shape {geo.shape}"
        )
