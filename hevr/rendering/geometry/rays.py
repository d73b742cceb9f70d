"""Ray/box clipping and sample positions (plaintext, vectorised numpy).

Conventions (API.md, "Geometry conventions"): a volume of shape (nz, ny, nx) has voxel
(k, j, i) centred at world point (i*sx, j*sy, k*sz). Rays are clipped to the closed box of
voxel centres ``[0, (nx-1)sx] x [0, (ny-1)sy] x [0, (nz-1)sz]``; a ray on a face is
inside. Rays start at ``t = 0`` (nothing behind the camera or the parallel image plane is
rendered). Samples sit at ``t_enter + k*step`` for ``k = 0 .. n-1`` with
``n = floor((t_exit - t_enter)/step + 1e-9) + 1``. A slice plane's rays
(:class:`~hevr.rendering.geometry.plane.Plane`) are its pixels' slabs: samples at ``t = k·slab_step``,
those inside the box (one run, the box being convex) kept.

Casting allocates a few arrays per ray (memory linear in ``width*height``), never per
sample; a ray of more than :data:`MAX_RAY_SAMPLES` samples (a step far below the volume's
size) is refused with :class:`hevr.RenderPlanError` instead of overflowing int64. How many
pixels and samples a render may have is decided before, by
:func:`hevr.rendering.planning.planner.check_render_size`.

Every consumer of sample positions -- the plaintext renderer and the per-brick weights of
the encrypted path -- goes through :func:`sample_positions`, :func:`nearest_voxels` and
:func:`trilinear_corners`, so both see bit-identical floating point (this matters for
``floor(p + 0.5)`` at exact halves and for the summation order of trilinear weights).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from array_api_compat import array_namespace

from ...core.validate import check_shape, check_spacing, check_step
from ...errors import ParameterError, RenderPlanError
from .camera import Camera
from .plane import Plane

__all__ = [
    "MAX_RAY_SAMPLES",
    "RaySet",
    "cast_rays",
    "corner_index",
    "expand_samples",
    "nearest_voxels",
    "sample_positions",
    "trilinear_corners",
]

# Direction components smaller than this (unit vectors) are treated as exactly parallel
# to the slab: the slab test then degenerates to "is the origin inside (with tolerance)".
_PARALLEL_DIR = 1e-12
# Relative tolerance of the face / hit tests ("rays on a face are inside").
_FACE_TOL = 1e-9
# Most samples one ray may have: 2^53, where float64 still counts every integer (and far
# from int64 overflow). No render limit (hevr.limits.max-samples) may exceed it.
MAX_RAY_SAMPLES = 2**53


@dataclass(frozen=True, eq=False)
class RaySet:
    """One ray per pixel, clipped to the voxel-centre box.

    Attributes
    ----------
    origins, directions : (N, 3) float64
        World-space rays, ``N = width*height``, index ``row*width + col``; unit directions.
    t_enter, t_exit : (N,) float64
        Clipped parameter interval (``0, 0`` for rays that miss).
    n_samples : (N,) int64
        Number of samples, 0 for rays that miss.
    width, height : int
        Image size.
    pixel_ids : (N,) int64 or None
        Global pixel index ``row*width + col`` of each ray when the set is a subset of the
        image (sorted, unique); None when it holds every pixel in order.
    """

    origins: np.ndarray
    directions: np.ndarray
    t_enter: np.ndarray
    t_exit: np.ndarray
    n_samples: np.ndarray
    width: int
    height: int
    pixel_ids: np.ndarray | None = None
    t_index: np.ndarray | None = None  # planes: sample k sits at t = (t_index + k)·step from the origin

    @property
    def n_rays(self) -> int:
        """Number of rays (``width*height`` unless a subset)."""
        return int(self.n_samples.shape[0])

    def global_ids(self, local: Any) -> Any:
        """Global pixel indices of rays given by their position in this set (the namespace of
        ``local``)."""
        xp = array_namespace(local)
        local = xp.astype(local, xp.int64)
        return local if self.pixel_ids is None else xp.take(xp.asarray(self.pixel_ids), local)

    def to_namespace(self, xp: Any) -> RaySet:
        """The same rays with every array in array namespace ``xp`` (e.g. CuPy's, or
        ``array_api_strict`` in the tests): what the namespace-generic geometry then runs on."""
        return RaySet(
            **{
                f.name: xp.asarray(getattr(self, f.name))
                if isinstance(getattr(self, f.name), np.ndarray)
                else getattr(self, f.name)
                for f in fields(self)
            }
        )


def cast_rays(camera: Camera | Plane, shape: Any, spacing: Any, step: float, pixels: Any = None) -> RaySet:
    """Cast the camera's rays and clip them to the voxel-centre box.

    Parameters
    ----------
    camera : Camera or Plane
        A :class:`~hevr.rendering.geometry.plane.Plane`'s rays are its pixels' slabs
        (:func:`_cast_plane`); ``step`` must then be its ``slab_step``.
    shape : (nz, ny, nx)
    spacing : (sx, sy, sz)
        World order.
    step : float
        Sample distance in world units, > 0.
    pixels : array of int, optional
        Only these pixels (global indices, made sorted and unique); every ray is computed
        elementwise, so they equal the same rays of the whole image bit for bit.

    Returns
    -------
    RaySet

    Examples
    --------
    >>> cam = Camera((1, 1, 10), (1, 1, 0), width=1, height=1, parallel=True)
    >>> rs = cast_rays(cam, (5, 3, 3), (1, 1, 1), 1.0)
    >>> rs.t_enter.tolist(), rs.t_exit.tolist(), rs.n_samples.tolist()
    ([6.0], [10.0], [5])
    """
    if isinstance(camera, Plane):
        return _cast_plane(camera, shape, spacing, step, pixels)
    if not isinstance(camera, Camera):
        raise ParameterError(f"camera: expected a hevr.Camera or hevr.Plane, got {type(camera).__name__}")
    nz, ny, nx = check_shape(shape)
    sp = np.asarray(check_spacing(spacing))
    step = check_step(step)
    ids = None
    if pixels is not None:
        ids = np.unique(camera.check_pixels(pixels))
    origins, dirs = camera.rays(ids)
    with np.errstate(over="ignore"):  # a box beyond float range: inf, every ray misses
        hi = np.array([(nx - 1), (ny - 1), (nz - 1)], dtype=np.float64) * sp
    # Absolute tolerance of the face tests, relative to the box size (at least a voxel).
    tol = _FACE_TOL * np.maximum(hi, sp)
    parallel = np.abs(dirs) < _PARALLEL_DIR
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t1 = (0.0 - origins) / dirs
        t2 = (hi - origins) / dirs
    tmin = np.where(parallel, -np.inf, np.minimum(t1, t2))
    tmax = np.where(parallel, np.inf, np.maximum(t1, t2))
    inside_slab = ~parallel | ((origins >= -tol) & (origins <= hi + tol))
    t_enter = np.maximum(tmin.max(axis=1), 0.0)
    t_exit = tmax.min(axis=1)
    # A ray grazing an edge or corner may have t_exit a hair below t_enter by rounding.
    t_tol = _FACE_TOL * max(step, float(np.linalg.norm(hi)))
    hit = inside_slab.all(axis=1) & (t_exit >= t_enter - t_tol) & np.isfinite(t_exit)
    t_exit = np.where(hit, np.maximum(t_exit, t_enter), 0.0)
    t_enter = np.where(hit, t_enter, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        span = np.where(hit, np.floor((t_exit - t_enter) / step + 1e-9), 0.0)
    if not np.all(span < MAX_RAY_SAMPLES):  # also catches inf / nan from an extreme step
        raise RenderPlanError(
            f"step: expected at most 2^53 samples along one ray, got a ray of "
            f"{float(np.nanmax(span)):.3g} samples at step {step:g}"
        )
    n = np.where(hit, span.astype(np.int64) + 1, 0)
    return RaySet(
        origins=origins,
        directions=dirs,
        t_enter=t_enter,
        t_exit=t_exit,
        n_samples=n.astype(np.int64),
        width=camera.width,
        height=camera.height,
        pixel_ids=ids,
    )


def _cast_plane(plane: Plane, shape: Any, spacing: Any, step: Any, pixels: Any = None) -> RaySet:
    """A plane's rays: per pixel, the run of its slab samples inside the voxel-centre box.

    Ray (r, c) has direction n; slab sample k sits at ``t = k·h`` from the first slab sample
    (h = ``slab_step`` = ``step``), k = 0 .. slab - 1. A sample is inside when it lies
    in the box widened by the face tolerance of :func:`cast_rays` on every axis; the box is
    convex, so the inside samples are one run ``k0 .. k1``, found per axis from the line's
    parameter interval in the widened box: ``k0 = ceil(t_min/h)``, ``k1 = floor(t_max/h)``,
    clipped to the slab, and ``n = k1 - k0 + 1`` (0: the pixel has no value). The returned rays
    start at the pixel centres with ``t_index = k0 - (slab - 1)/2``, and :func:`sample_positions`
    places sample k at ``centre + ((t_index + k)·h)·n``: the definition's own arithmetic.

    >>> rs = cast_rays(Plane((0, 0, 1), (1, 0, 0), (0, 1, 0), 3, 1, slab=5), (3, 2, 2), (1, 1, 1), 1.0)
    >>> rs.t_index.tolist(), rs.n_samples.tolist()
    ([-1.0, -1.0, 0.0], [3, 3, 0])
    """
    nz, ny, nx = check_shape(shape)
    sp = np.asarray(check_spacing(spacing))
    step = check_step(step)
    if step != plane.slab_step:
        raise ParameterError(
            f"step: expected the plane's slab_step {plane.slab_step:g} (a plane's samples are "
            f"its slab's planes), got {step:g}"
        )
    ids = None if pixels is None else np.unique(plane.check_pixels(pixels))
    origins, dirs = plane.rays(ids)
    with np.errstate(over="ignore"):
        hi = np.array([(nx - 1), (ny - 1), (nz - 1)], dtype=np.float64) * sp
    tol = _FACE_TOL * np.maximum(hi, sp)
    lo_b, hi_b = -tol, hi + tol
    parallel = np.abs(dirs) < _PARALLEL_DIR
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t1 = (lo_b - origins) / dirs
        t2 = (hi_b - origins) / dirs
        tmin = np.where(parallel, -np.inf, np.minimum(t1, t2)).max(axis=1)
        tmax = np.where(parallel, np.inf, np.maximum(t1, t2)).min(axis=1)
        k0 = np.clip(np.ceil(tmin / step), 0, plane.slab)
        k1 = np.clip(np.floor(tmax / step), -1, plane.slab - 1)
    inside_slab = (~parallel | ((origins >= lo_b) & (origins <= hi_b))).all(axis=1)
    hit = inside_slab & (k1 >= k0)  # NaN (a box beyond float range) compares False: a miss
    k0 = np.where(hit, k0, 0.0).astype(np.int64)
    n = np.where(hit, np.where(hit, k1, 0.0).astype(np.int64) - k0 + 1, 0).astype(np.int64)
    # Samples are placed from the pixel centre, t = (k - (S-1)/2)·h, exactly as the definition
    # (and render_slice_plain) writes them: the same float operations, so the same voxel at ties.
    index0 = np.where(hit, k0 - (plane.slab - 1) / 2.0, 0.0)
    return RaySet(
        origins=plane.centres(ids),
        directions=dirs,
        t_enter=index0 * step,
        t_exit=np.where(hit, (index0 + n - 1) * step, 0.0),
        n_samples=n,
        width=plane.width,
        height=plane.height,
        pixel_ids=ids,
        t_index=index0,
    )


def sample_positions(rays: RaySet, ray_idx: np.ndarray, k: np.ndarray, spacing: Any, step: float) -> np.ndarray:
    """Sample positions in voxel-index space, (m, 3) float64 with columns (i, j, k).

    ``p = (origin + (t_enter + k*step)*direction) / spacing`` evaluated elementwise, so
    the result for a (ray, k) pair does not depend on which other pairs are computed with
    it. This is the single definition shared by the plaintext renderer and the weights.

    Examples
    --------
    >>> cam = Camera((1, 1, 10), (1, 1, 0), width=1, height=1, parallel=True)
    >>> rs = cast_rays(cam, (5, 3, 3), (1, 1, 2), 1.0)
    >>> sample_positions(rs, np.array([0, 0]), np.array([0, 4]), (1, 1, 2), 1.0).tolist()
    [[1.0, 1.0, 4.0], [1.0, 1.0, 2.0]]
    """
    xp = array_namespace(rays.origins)
    ray_idx = xp.astype(xp.asarray(ray_idx), xp.int64)
    k = xp.astype(xp.asarray(k), xp.float64)  # int64 -> float64, as numpy's mixed arithmetic does
    if rays.t_index is not None:  # a plane: t = (first index + k)·h, from the pixel centre
        t = (xp.take(rays.t_index, ray_idx) + k) * float(step)
    else:
        t = xp.take(rays.t_enter, ray_idx) + k * float(step)
    world = xp.take(rays.origins, ray_idx, axis=0) + t[:, None] * xp.take(rays.directions, ray_idx, axis=0)
    return world / xp.asarray([float(s) for s in spacing], dtype=xp.float64)


def nearest_voxels(p: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """Nearest voxel ``floor(p + 0.5)`` (round half up), clamped to the box.

    Parameters
    ----------
    p : (m, 3) float64, columns (i, j, k)
    shape : (nz, ny, nx)

    Returns
    -------
    (m, 3) int64, columns (i, j, k)

    Examples
    --------
    >>> nearest_voxels(np.array([[0.5, 1.49, -0.2]]), (2, 2, 2)).tolist()
    [[1, 1, 0]]
    """
    xp = array_namespace(p)
    upper = xp.asarray([shape[2] - 1, shape[1] - 1, shape[0] - 1], dtype=xp.int64)
    idx = xp.astype(xp.floor(p + 0.5), xp.int64)
    return xp.minimum(xp.maximum(idx, 0), upper)  # np.clip's arithmetic (clip's array bounds are slow)


def trilinear_corners(p: np.ndarray, shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 8 trilinear corners of each sample: clamped lower/upper indices and weights.

    Corner ``c`` (0..7) uses the upper index along x if ``c & 1``, along y if ``c & 2``
    and along z if ``c & 4`` (see :func:`corner_index`). Indices are clamped to the box;
    two corners that clamp to the same voxel each keep their weight (callers that sum
    per voxel thereby add them).

    Returns
    -------
    lo, hi : (m, 3) int64, columns (i, j, k)
        Clamped ``floor(p)`` and ``floor(p) + 1``.
    w : (m, 8) float64
        Corner weights ``(wx*wy)*wz``; rows sum to 1 up to rounding.

    Examples
    --------
    >>> lo, hi, w = trilinear_corners(np.array([[0.25, 0.0, 0.0]]), (1, 1, 2))
    >>> lo.tolist(), hi.tolist(), w[0, :2].tolist()
    ([[0, 0, 0]], [[1, 0, 0]], [0.75, 0.25])
    """
    upper = np.array([shape[2] - 1, shape[1] - 1, shape[0] - 1], dtype=np.int64)
    base = np.floor(p)
    frac = p - base
    base = base.astype(np.int64)
    lo = np.clip(base, 0, upper)
    hi = np.clip(base + 1, 0, upper)
    wl = 1.0 - frac
    w = np.empty((p.shape[0], 8), dtype=np.float64)
    for cy in (0, 1):
        wy = frac[:, 1] if cy else wl[:, 1]
        for cx in (0, 1):
            wxy = (frac[:, 0] if cx else wl[:, 0]) * wy
            w[:, cx | (cy << 1)] = wxy * wl[:, 2]
            w[:, cx | (cy << 1) | 4] = wxy * frac[:, 2]
    return lo, hi, w


def corner_index(lo: np.ndarray, hi: np.ndarray, corner: int) -> np.ndarray:
    """Per-axis indices (m, 3) of trilinear corner ``corner`` (see :func:`trilinear_corners`).

    Examples
    --------
    >>> corner_index(np.array([[0, 0, 0]]), np.array([[1, 1, 1]]), 5).tolist()
    [[1, 0, 1]]
    """
    out = lo.copy()
    for a in range(3):
        if (corner >> a) & 1:
            out[:, a] = hi[:, a]
    return out


def expand_samples(ray_ids: np.ndarray, k_first: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Enumerate sample (ray, k) pairs, ray-major, k ascending within each ray.

    Ray ``ray_ids[r]`` contributes ``k = k_first[r] .. k_first[r] + counts[r] - 1``.

    Examples
    --------
    >>> r, k = expand_samples(np.array([3, 5]), np.array([0, 2]), np.array([2, 3]))
    >>> r.tolist(), k.tolist()
    ([3, 3, 5, 5, 5], [0, 1, 2, 3, 4])
    """
    xp = array_namespace(ray_ids, k_first, counts)
    counts = xp.astype(xp.asarray(counts), xp.int64)
    total = int(xp.sum(counts))
    ray_idx = xp.repeat(xp.astype(xp.asarray(ray_ids), xp.int64), counts)
    # k = k_first + (position within the ray's run) = arange - run start + k_first.
    shift = xp.repeat(xp.astype(xp.asarray(k_first), xp.int64) - (xp.cumulative_sum(counts) - counts), counts)
    return ray_idx, xp.arange(total, dtype=xp.int64) + shift
