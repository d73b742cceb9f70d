"""The plaintext reference renderer: a direct, vectorised numpy ray marcher.

It implements API.md's rendering equations on an unencrypted volume so the encrypted
path can be checked against it:

* ``xray``: ``(1/n) sum value`` of the raw voxel values (as float64);
* ``emphasize``: ``(1/n) sum dot(s, e(density))``;
* ``tf``: ``(1/(n K)) sum_samples sum_i dot(s, e(d_i)) c_i``;

where ``s`` is the sampled (nearest or trilinearly interpolated) encoded vector of the
voxels' normalised densities — with ``gradient=True`` the sampled ``g·e(d)`` instead, the
field the writer stores in the gradient channel (:func:`hevr.volume.gradient.gradient_encoding`,
the same float64 values before quantisation). Because both vector modes are linear in ``s`` the renderer
first maps every voxel to ``e(density) @ M`` (M from :func:`hevr.rendering.planning.modes.combination_matrix`)
and then interpolates that 1- or 3-channel field, which is the same sum in another order.
:func:`render_slice_plain` is the slices' reference: it evaluates every slab sample of every
pixel directly from the plane's definition (no ray casting, its own nearest and trilinear
lookups), so it checks :func:`hevr.render_slice` by a second implementation.
Rays are processed in chunks of about ``_CHUNK_SAMPLES`` samples, and a ray longer than
``_RAY_PIECE`` samples in pieces, so memory stays bounded however long the rays are; renders
above the size limits (:func:`hevr.rendering.planning.planner.check_render_size`) are refused first.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from ...core.validate import check_spacing, check_vector_dims
from ...core.voxels import check_data_range, check_volume
from ...errors import ParameterError
from ...volume.density import default_value_range, encode_density, normalize_density
from ...volume.gradient import gradient_encoding
from ...volume.pyramid import check_level, downsample, level_origin, level_spacing
from ...volume.scan import Scan
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from ..geometry.rays import (
    cast_rays,
    expand_samples,
    nearest_voxels,
    sample_positions,
    trilinear_corners,
)
from ..packed.sliced import render_plain_field_slices, render_plain_slices
from ..planning.modes import RenderSpec, combination_matrix, make_spec
from ..planning.planner import check_render_size

__all__ = ["render_plain", "render_slice_plain", "DEFAULT_VECTOR_DIMS"]

logger = logging.getLogger(__name__)

DEFAULT_VECTOR_DIMS = 4
# Samples per chunk: trilinear keeps ~8 (m, C) float64 temporaries alive, so 2**18
# samples stay well under 100 MB.
_CHUNK_SAMPLES = 1 << 18
# A ray with more samples than this is summed in pieces of this many (bounded memory).
_RAY_PIECE = 1 << 18
# Integer volumes whose value span is at most this use a lookup table per value.
_LUT_MAX = 1 << 16

Field = Callable[[np.ndarray], np.ndarray]


def _check_volume(vol: Any, spacing: Any) -> tuple[np.ndarray, Any]:
    """The volume as a numpy array (3-D, non-empty, bool/integer/float, finite values) and its
    spacing: ``spacing``, else a :class:`~hevr.volume.scan.Scan`'s own, else (1, 1, 1)."""
    if isinstance(vol, Scan):
        vol, spacing = vol.volume, vol.spacing if spacing is None else spacing
    arr = check_volume(np.asarray(vol))
    if arr.dtype.kind == "f":
        check_data_range(arr.min(), arr.max())
    return arr, (1, 1, 1) if spacing is None else spacing


def _make_field(
    arr: np.ndarray, spec: RenderSpec, value_range: Any, dims: int | None, spacing: Any = (1, 1, 1)
) -> tuple[Field, int]:
    """Return ``field(flat_voxel_indices) -> (m, C) float64`` and C (``spacing``: the gradient's world units)."""
    flat = arr.reshape(-1)
    if not spec.needs_vector:
        return (lambda idx: flat[idx].astype(np.float64)[:, None]), 1
    assert dims is not None
    matrix = combination_matrix(spec, dims)
    rng = default_value_range(arr) if value_range is None else value_range
    channels = matrix.shape[1]
    if spec.gradient:  # g·e(d) of every voxel, from the whole volume's gradient, times the matrix
        table = gradient_encoding(arr, spacing, rng, dims).reshape(-1, dims) @ matrix
        return (lambda idx: table[idx]), channels
    if arr.dtype == np.bool_ or np.issubdtype(arr.dtype, np.integer):
        lo, hi = int(flat.min()), int(flat.max())
        if hi - lo < _LUT_MAX:
            # One encoding per distinct value instead of one per voxel sample.
            lut = encode_density(normalize_density(np.arange(lo, hi + 1), rng), dims) @ matrix
            return (lambda idx: lut[flat[idx].astype(np.int64) - lo]), channels
    return (lambda idx: encode_density(normalize_density(flat[idx], rng), dims) @ matrix), channels


def _pieces(rays: np.ndarray, counts: np.ndarray, piece: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split rays longer than ``piece`` samples: (ray ids, first k, counts) of the pieces.

    >>> [a.tolist() for a in _pieces(np.array([4, 7]), np.array([5, 2]), 2)]
    [[4, 4, 4, 7], [0, 2, 4, 0], [2, 2, 1, 2]]
    """
    n_pieces = -(-counts // piece)
    ray_ids = np.repeat(rays, n_pieces)
    index = np.arange(int(n_pieces.sum()), dtype=np.int64) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces)
    k_first = index * piece
    return ray_ids, k_first, np.minimum(piece, np.repeat(counts, n_pieces) - k_first)


def _chunks(counts: np.ndarray, limit: int) -> list[tuple[int, int]]:
    """Split consecutive rays into [a, b) runs of about ``limit`` samples each."""
    csum = np.cumsum(counts)
    bounds = [0]
    while bounds[-1] < len(counts):
        start = bounds[-1]
        base = csum[start - 1] if start else 0
        end = int(np.searchsorted(csum, base + limit, side="right"))
        bounds.append(max(end, start + 1))
    return list(zip(bounds[:-1], bounds[1:]))


def render_plain(
    vol: Any,
    camera: Camera,
    mode: str = "xray",
    sampling: str = "nearest",
    step: float = 1.0,
    spacing: Any = None,
    value_range: Any = None,
    vector_dims: int | None = None,
    density: float | None = None,
    nodes: Any = None,
    level: int = 0,
    gradient: bool = False,
    slices: bool | int | str = False,
) -> np.ndarray:
    """Render a plaintext volume; the reference for the encrypted renderer.

    Parameters
    ----------
    vol : array_like, shape (nz, ny, nx), or Scan
        Bool, integer or float voxel values, or a :class:`hevr.Scan` (:func:`hevr.read_scan`),
        which brings its spacing (as :func:`hevr.encrypt_volume` takes it).
    camera : Camera
    mode : {'xray', 'emphasize', 'tf'}
    sampling : {'nearest', 'trilinear'}
    step : float
        Sample distance in world units.
    spacing : (sx, sy, sz), optional
        World-order voxel spacing; default the scan's, else (1, 1, 1).
    value_range : (lo, hi) or None
        Density normalisation for emphasize/tf; default: integer dtypes -> full dtype
        range, floats -> data (min, max).
    vector_dims : int or None
        Length k of the density encoding (emphasize/tf), 2 .. 64; default 4.
    density : float
        Emphasised density in [0, 1] (emphasize).
    nodes : list of (density, color)
        Transfer-function nodes (tf); colours as accepted by :func:`hevr.rendering.planning.modes.parse_color`.
    level : int
        Render pyramid level ``level`` (:mod:`hevr.volume.pyramid`): the per-voxel field (values,
        or encoded density vectors times the combination matrix) averaged over 2×2×2 children
        ``level`` times, on the level's grid, with the same camera, sampled every
        ``step·2^level`` world units.
    gradient : bool
        ``emphasize`` / ``tf`` only: sample ``g·e(d)`` instead of ``e(d)`` — ``g`` the voxel's
        gradient magnitude (central differences in world units, ``spacing``) over the whole
        volume's largest (:mod:`hevr.volume.gradient`); the reference of
        ``hevr.render(..., gradient=True)``.
    slices : bool, int or {"z", "y", "x"}
        Sample slice by slice, as a packed store's frame does (:mod:`hevr.rendering.packed`): one
        sample per slice of the view's principal axis, nearest or (``"trilinear"``) bilinear within
        the slice, then the warp to the pixels; a parallel camera, ``step`` 1, X-ray, or emphasis
        and transfer functions (the per-voxel field e(d)·M/N sampled alike, level 0). The
        reference of ``hevr.render`` on a packed store (:mod:`hevr.rendering.packed.sliced`):
        ``True`` for a store packed along z (the default), else its packing axis (the rays
        along it are one voxel apart, as the packs' lattice makes them). With ``level``: the
        slices of the level's means (a packed store's level, :mod:`hevr.store.packed_levels`).

    Returns
    -------
    np.ndarray
        float64, (height, width) or (height, width, 3) for ``tf``; 0 where rays miss.

    Examples
    --------
    >>> vol = np.arange(27, dtype=np.uint8).reshape(3, 3, 3)
    >>> cam = Camera.orbit(vol.shape, width=4, height=4)
    >>> render_plain(vol, cam).shape
    (4, 4)
    """
    if slices is not False:
        axes = {"z": 0, "y": 1, "x": 2, 0: 0, 1: 1, 2: 2}  # True == 1 as a key: taken apart first
        axis = 0 if slices is True else axes.get(slices) if isinstance(slices, str) or type(slices) is int else None
        if axis is None:
            raise ParameterError(
                f"slices: expected True, False or a packing axis (0, 1, 2, 'z', 'y', 'x'), got {slices!r}"
            )
        if (gradient and mode == "xray") or type(step) not in (int, float) or float(step) != 1.0:
            raise ParameterError(
                f"slices: expected mode='xray', step=1 and gradient=False with slice "
                f"sampling ('emphasize' and 'tf' too, with or without gradient: a packed store's "
                f"vector and gradient channels), got mode={mode!r}, step={step!r}, "
                f"gradient={gradient!r}"
            )
        if mode != "xray":  # the per-voxel field e(d)·M / N (as below), slice-sampled: hevr.rendering.packed.colour
            if check_level(level):
                raise ParameterError(
                    f"level: expected 0 for mode={mode!r} with slice sampling (a packed store's "
                    f"levels hold the scalar channel only), got {level!r}"
                )
            arr, sp = _check_volume(vol, spacing)
            n_dims = DEFAULT_VECTOR_DIMS if vector_dims is None else int(check_vector_dims(vector_dims))
            spec = make_spec(mode, sampling, 1.0, density, nodes, n_dims, gradient=gradient, has_gradient=True)
            field, channels = _make_field(arr, spec, value_range, n_dims, check_spacing(sp))
            values = field(np.arange(arr.size)).reshape(arr.shape + (channels,)) / spec.n_nodes
            out = render_plain_field_slices(values, camera, spec.sampling, sp, axis=axis)
            return out.reshape(spec.image_shape(camera.height, camera.width))
        if check_level(level):  # a packed store's level (hevr.store.packed_levels): the means, on the level's grid
            arr, sp = _check_volume(vol, spacing)
            shift = np.asarray(level_origin(check_spacing(sp), level))
            camera = dataclasses.replace(
                camera,
                position=tuple((np.asarray(camera.position) - shift).tolist()),
                focal_point=tuple((np.asarray(camera.focal_point) - shift).tolist()),
            )
            vol, spacing = downsample(arr, level), level_spacing(check_spacing(sp), level)
        return render_plain_slices(vol, camera, sampling, spacing, axis=axis)
    arr, spacing = _check_volume(vol, spacing)
    dims = None
    if mode in ("emphasize", "tf"):
        dims = DEFAULT_VECTOR_DIMS if vector_dims is None else check_vector_dims(vector_dims)
    spec = make_spec(mode, sampling, step, density, nodes, dims, gradient=gradient, has_gradient=True)
    if dims is not None:
        dims = int(dims)
    sp = check_spacing(spacing)
    field, channels = _make_field(arr, spec, value_range, dims, sp)
    level = check_level(level)
    if level:  # the pyramid's definition: means of the per-voxel field, on the level's grid
        if not isinstance(camera, Camera):
            raise ParameterError(f"camera: expected a hevr.Camera, got {type(camera).__name__}")
        coarse = downsample(field(np.arange(arr.size)).reshape(arr.shape + (channels,)), level)
        flat_field = coarse.reshape(-1, channels)
        arr = np.empty(coarse.shape[:3], dtype=np.uint8)  # only its shape is used from here on
        field = lambda idx: flat_field[idx]  # noqa: E731
        shift = np.asarray(level_origin(sp, level))
        camera = dataclasses.replace(
            camera,
            position=tuple((np.asarray(camera.position) - shift).tolist()),
            focal_point=tuple((np.asarray(camera.focal_point) - shift).tolist()),
        )
        sp = level_spacing(sp, level)
        spec = dataclasses.replace(spec, step=spec.step * 2**level)  # sampled in the level's voxels
    checked = check_render_size(camera, arr.shape, sp, spec.step)  # before anything per pixel or sample
    rays = checked if checked is not None else cast_rays(camera, arr.shape, sp, spec.step)
    nz, ny, nx = arr.shape
    strides = np.array([1, nx, nx * ny], dtype=np.int64)  # (i, j, k) -> flat C-order index

    hits = np.flatnonzero(rays.n_samples > 0)
    ray_ids, k_first, counts = _pieces(hits, rays.n_samples[hits], _RAY_PIECE)
    sums = np.zeros((rays.n_rays, channels), dtype=np.float64)
    for a, b in _chunks(counts, _CHUNK_SAMPLES) if hits.size else []:
        ray_idx, k = expand_samples(ray_ids[a:b], k_first[a:b], counts[a:b])
        p = sample_positions(rays, ray_idx, k, sp, spec.step)
        if spec.sampling == "nearest":
            vals = field(nearest_voxels(p, arr.shape) @ strides)
        else:
            lo, hi, w = trilinear_corners(p, arr.shape)
            lo_f, hi_f = lo * strides, hi * strides  # per-axis flat offsets
            vals = np.zeros((p.shape[0], channels), dtype=np.float64)
            for c in range(8):
                x, y, z = ((hi_f if (c >> ax) & 1 else lo_f)[:, ax] for ax in range(3))
                off = x + y + z
                vals += w[:, c, None] * field(off)
        starts = np.concatenate(([0], np.cumsum(counts[a:b])[:-1]))
        np.add.at(sums, ray_ids[a:b], np.add.reduceat(vals, starts, axis=0))  # pieces of a ray add up

    n = rays.n_samples.astype(np.float64) * spec.n_nodes
    out = np.divide(sums, n[:, None], out=np.zeros_like(sums), where=n[:, None] > 0)
    logger.debug("render_plain: %d rays, %d samples, mode=%s", rays.n_rays, int(counts.sum()), mode)
    return out.reshape(spec.image_shape(rays.height, rays.width))


def render_slice_plain(
    vol: Any,
    plane: Plane,
    mode: str = "xray",
    sampling: str = "nearest",
    spacing: Any = None,
    value_range: Any = None,
    vector_dims: int | None = None,
    density: float | None = None,
    nodes: Any = None,
    gradient: bool = False,
) -> np.ndarray:
    """Slice a plaintext volume; the reference for :func:`hevr.render_slice`.

    Each pixel (r, c) averages the mode's quantity over its slab samples
    ``origin + c·du·u + r·dv·v + (k - (S - 1)/2)·slab_step·n`` that lie in the closed
    voxel-centre box (1e-9 relative tolerance), sampled as API.md defines: nearest
    ``floor(p + 0.5)``, trilinear over the 8 surrounding voxels, indices clamped to the box.
    A pixel without such a sample is 0. Arguments as for :func:`render_plain`, ``plane`` a
    :class:`~hevr.rendering.geometry.plane.Plane`.

    Returns
    -------
    np.ndarray
        float64, (height, width) or (height, width, 3) for ``tf``.

    Examples
    --------
    >>> vol = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)
    >>> bool((render_slice_plain(vol, Plane.axial(vol.shape, 1)) == vol[1]).all())
    True
    >>> render_slice_plain(vol, Plane.axial(vol.shape, 0.5), sampling="trilinear")[0].tolist()
    [6.0, 7.0, 8.0, 9.0]
    """
    arr, spacing = _check_volume(vol, spacing)
    if not isinstance(plane, Plane):
        raise ParameterError(f"plane: expected a hevr.Plane, got {type(plane).__name__}")
    dims = None
    if mode in ("emphasize", "tf"):
        dims = DEFAULT_VECTOR_DIMS if vector_dims is None else int(check_vector_dims(vector_dims))
    spec = make_spec(mode, sampling, plane.slab_step, density, nodes, dims, gradient=gradient, has_gradient=True)
    sp = np.asarray(check_spacing(spacing), dtype=np.float64)
    check_render_size(plane, arr.shape, tuple(sp), plane.slab_step)
    field, channels = _make_field(arr, spec, value_range, dims, tuple(sp))
    nz, ny, nx = arr.shape
    upper = np.array([nx - 1, ny - 1, nz - 1], dtype=np.int64)
    strides = np.array([1, nx, nx * ny], dtype=np.int64)
    box = upper * sp
    tol = 1e-9 * np.maximum(box, sp)
    u, v = np.asarray(plane.u, dtype=np.float64), np.asarray(plane.v, dtype=np.float64)
    normal = np.cross(u, v)
    normal /= np.linalg.norm(normal)
    du, dv = plane.pixel_spacing
    n_pix = plane.width * plane.height
    sums = np.zeros((n_pix, channels), dtype=np.float64)
    counts = np.zeros(n_pix, dtype=np.int64)
    for a in range(0, n_pix, _CHUNK_SAMPLES):
        pix = np.arange(a, min(a + _CHUNK_SAMPLES, n_pix), dtype=np.int64)
        rows, cols = np.divmod(pix, plane.width)
        centre = np.asarray(plane.origin) + (cols * du)[:, None] * u + (rows * dv)[:, None] * v
        for k in range(plane.slab):
            world = centre + ((k - (plane.slab - 1) / 2.0) * plane.slab_step) * normal
            inside = np.all((world >= -tol) & (world <= box + tol), axis=1)
            p = world[inside] / sp
            if spec.sampling == "nearest":
                vals = field(np.clip(np.floor(p + 0.5).astype(np.int64), 0, upper) @ strides)
            else:
                base = np.floor(p)
                frac = p - base
                vals = np.zeros((p.shape[0], channels), dtype=np.float64)
                for corner in range(8):
                    bits = np.array([(corner >> ax) & 1 for ax in range(3)])
                    idx = np.clip(base.astype(np.int64) + bits, 0, upper)
                    w = np.prod(np.where(bits == 1, frac, 1.0 - frac), axis=1)
                    vals += w[:, None] * field(idx @ strides)
            sums[pix[inside]] += vals
            counts[pix[inside]] += 1
    n = counts.astype(np.float64) * spec.n_nodes
    out = np.divide(sums, n[:, None], out=np.zeros_like(sums), where=n[:, None] > 0)
    return out.reshape(spec.image_shape(plane.height, plane.width))
