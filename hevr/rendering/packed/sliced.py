"""The float64 reference of slice-sampled frames, and the bound of a packed frame against it.

:func:`render_plain_slices` (``hevr.render_plain(..., slices=True)``) samples every slice of the
view's principal axis once per intermediate ray, with float64 in-slice weights (nearest: the voxel
at floor(x + 0.5); ``trilinear``: bilinear within the slice, zero outside the volume), divides by
the sample count and warps to the pixels — the definitions of :mod:`hevr.rendering.packed.shear`,
evaluated directly on the plaintext slice by slice (no packing, no quantised weights, no accumulators).
The geometry (slopes, which rays, the warp) is the shared public part; the sums are its own.

:func:`packed_error_bound`: per pixel, how far a decrypted packed frame may be from it. Per
contributing slice the four bilinear weights, each rounded to a multiple of 1/U (U =
2^weight_bits), move a sample by at most 4·(0.5/U)·V = 2V/U, V = max(|lo|, |hi|) of the value
range; a float store's mantissas add 0.5·10^exponent·(1 + 2/U). A ray with n samples and C
contributing slices (C > n only where samples fall just outside the box) is off by at most
C·(2V/U + store)/n; the warp's convex weights carry the bound to the pixels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...colour import Colouring
from ...core.validate import check_choice, check_spacing
from ...core.voxels import check_volume
from ...errors import ParameterError
from ...volume.scan import Scan
from ..planning.planner import check_render_size
from .plan import SlicePlan
from .shear import ShearGeometry

__all__ = ["render_plain_field_slices", "render_plain_slices", "packed_error_bound"]


def render_plain_slices(
    vol: Any, camera: Any, sampling: str = "nearest", spacing: Any = None, axis: int = 0
) -> np.ndarray:
    """The X-ray of ``camera`` (parallel) on ``vol``, sampled slice by slice: (H, W) float64.

    ``axis``: the packing axis of the store compared with: its rays are one voxel apart (the packs'
    lattice; the rows along the third axis follow the pixels), and views along it are refused as
    the store refuses them."""
    if isinstance(vol, Scan):
        vol, spacing = vol.volume, vol.spacing if spacing is None else spacing
    arr = check_volume(np.asarray(vol))
    spacing = check_spacing((1.0, 1.0, 1.0) if spacing is None else spacing)
    sampling = check_choice("sampling", sampling, ("nearest", "trilinear"))
    check_render_size(camera, arr.shape, spacing, 1.0)
    geo = ShearGeometry.of(camera, arr.shape, spacing, axis=axis)
    inter = _intermediate(arr, geo, sampling)
    return geo.warp(inter, geo.pixel_coords(camera)).reshape(camera.height, camera.width)


def render_plain_field_slices(
    field: np.ndarray, camera: Any, sampling: str = "nearest", spacing: Any = None, axis: int = 0
) -> np.ndarray:
    """:func:`render_plain_slices` of every channel of a per-voxel ``field`` (nz, ny, nx, C) float64
    (``render_plain(..., mode="emphasize" | "tf", slices=True)``: the field e(d)·M/N of its
    voxels): (H, W, C) float64, each channel sampled slice by slice and warped alike."""
    f = np.asarray(field, dtype=np.float64)
    if f.ndim != 4 or not f.shape[-1] or not f.size:
        raise ParameterError(f"field: expected a non-empty (nz, ny, nx, C) array, got shape {f.shape}")
    spacing = check_spacing((1.0, 1.0, 1.0) if spacing is None else spacing)
    sampling = check_choice("sampling", sampling, ("nearest", "trilinear"))
    check_render_size(camera, f.shape[:3], spacing, 1.0)
    geo = ShearGeometry.of(camera, f.shape[:3], spacing, axis=axis)
    coords = geo.pixel_coords(camera)
    out = [geo.warp(_intermediate(f[..., c], geo, sampling), coords) for c in range(f.shape[-1])]
    return np.stack(out, axis=-1).reshape(camera.height, camera.width, f.shape[-1])


def _intermediate(arr: np.ndarray, geo: ShearGeometry, sampling: str) -> np.ndarray:
    """Σ samples / n of every intermediate ray, float64, slice by slice."""
    vol = np.moveaxis(arr, (geo.principal, geo.axis, geo.other), (0, 1, 2))
    na, nb = vol.shape[1], vol.shape[2]
    i = np.arange(*geo.i_range, dtype=np.float64)
    j = geo.row_positions()
    total = np.zeros((len(i), len(j)), np.float64)
    count = np.zeros((len(i), len(j)), np.int64)
    for k in range(vol.shape[0]):
        plane = vol[k].astype(np.float64)
        x, y = i + k * geo.slope_a, j + k * geo.slope_b
        if sampling == "nearest":
            xi, yi = np.floor(x + 0.5).astype(np.int64), np.floor(y + 0.5).astype(np.int64)
            oka, okb = (xi >= 0) & (xi < na), (yi >= 0) & (yi < nb)
            total[np.ix_(oka, okb)] += plane[np.ix_(xi[oka], yi[okb])]
            count += np.outer(oka, okb)
            continue
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            for dy, wy in ((0, 1.0 - fy), (1, fy)):
                xa, yb = x0 + dx, y0 + dy
                oka, okb = (xa >= 0) & (xa < na), (yb >= 0) & (yb < nb)
                total[np.ix_(oka, okb)] += np.outer(wx[oka], wy[okb]) * plane[np.ix_(xa[oka], yb[okb])]
        count += np.outer((x >= 0) & (x <= na - 1), (y >= 0) & (y <= nb - 1))
    out = np.zeros_like(total)
    np.divide(total, count, out=out, where=count > 0)
    return out


def packed_error_bound(
    meta: Any,
    camera: Any,
    sampling: str,
    weight_bits: int | None = None,
    mode: str = "xray",
    density: Any = None,
    nodes: Any = None,
) -> np.ndarray:
    """Per-pixel bound (H, W) on |decrypted packed frame − :func:`render_plain_slices`| (module
    docstring); ``mode`` ``"emphasize"`` / ``"tf"`` (a store with the vector channel): the bound
    against ``render_plain(..., mode=..., slices=True)``, (H, W) or (H, W, 3) (:func:`_colour_terms`)."""
    plan = SlicePlan.build(
        camera, meta.shape, meta.spacing, meta.brick, meta.packing, sampling, weight_bits=weight_bits
    )
    U = float(1 << plan.weight_bits)
    if mode == "xray":
        lo, hi = (float(v) for v in meta.value_range)
        D = max(abs(lo), abs(hi))
        store = 0.5 * 10.0**meta.scalar.exponent * (1 + 2 / U) if meta.scalar.digits is not None else 0.0
        scale, channels = 1.0, 1
    else:
        D, store, scale, channels = _colour_terms(meta, mode, density, nodes, U)
    weights = 2.0 * D / U if sampling == "trilinear" else 0.0
    n = plan.geometry.sample_counts(sampling)
    C = plan.contributing_slices()
    per_ray = np.zeros(n.shape, np.float64)
    np.divide(C * (weights + store), n, out=per_ray, where=n > 0)
    per_ray = per_ray * scale * 1.0001 + 1e-9 * max(D * scale, 1.0)  # float64 rounding of sums of up to N_p terms
    geo = plan.geometry
    b = geo.warp(per_ray, geo.pixel_coords(camera)).reshape(camera.height, camera.width) + 1e-9 * max(D * scale, 1.0)
    return np.repeat(b[..., None], channels, axis=2) if channels > 1 else b


def _colour_terms(meta: Any, mode: str, density: Any, nodes: Any, unit: float) -> tuple[float, float, float, int]:
    """The terms of a colour frame's bound (``emphasize`` / ``tf``, :mod:`hevr.rendering.packed.colour`):
    each component of e(d) lies in [0, 1] (D = 1) and is stored to 0.5·10^exponent (times the slice's
    weight total, at most 1 + 2/U), as a scalar sample is; the colouring then adds the components with
    the coefficients M[k, c]/N, so a colour is off by at most max_c Σ_k |M[k, c]|/N times a component's
    bound. Returns (D, store, that factor, colour channels)."""
    if meta.vector is None:
        raise ParameterError(f"mode: expected 'xray' for a packed store without the vector channel, got {mode!r}")
    colouring = Colouring(mode, density, nodes)
    M = colouring.matrix(int(meta.vector.dims)) / colouring.n_nodes
    store = 0.5 * 10.0**meta.vector.exponent * (1 + 2 / unit)
    return 1.0, store, float(np.abs(M).sum(axis=0).max()), colouring.channels
