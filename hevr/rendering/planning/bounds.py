"""``hevr.error_bound``: how far a decrypted pixel may be from :func:`hevr.render_plain`.

Error bound of a decrypted pixel against :func:`hevr.render_plain` (same camera/step), server
finishing (client finishing keeps the first two items only, :mod:`hevr.colour`):

* weights: nearest weights are exact counts; a trilinear pair weight is rounded to
  10^-digits, so the ray sum is off by at most P_r·0.5·10^-digits·max|q| (P_r <= 8·n_r
  pairs, q the stored per-voxel quantity), i.e. at most 4·10^-digits·max|q| per pixel;
* storage: float scalars are quantised to 10^-store_digits, vector components (and the
  gradient channel's g·e(d), components in [0, 1] too) to 10^-vector_digits
  (error <= 0.5·10^-vector_digits·Σ_k|Q_k| per sample for emphasize/tf);
* combination matrix: quantised to 10^-comb_digits (<= 0.5·10^-comb_digits·Σ_k s_k per
  sample, Σ_k s_k <= sqrt(k));
* normalisation: the reciprocal's relative error is <= 0.5·10^-precision.

:func:`error_bound` evaluates this for a given render.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import ParameterError
from ...store.reader import EncryptedVolume
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from ..geometry.rays import cast_rays
from ..packed.planes import packed_slice_error_bound
from ..packed.sliced import packed_error_bound
from .modes import combination_matrix
from .planner import check_render_size
from .request import at_level, check_request, level_step

__all__ = ["error_bound"]


def error_bound(
    ev: EncryptedVolume,
    camera: Camera | Plane,
    mode: str = "xray",
    sampling: str = "nearest",
    step: float = 1.0,
    density: float | None = None,
    nodes: Any = None,
    *,
    digits: int = 3,
    precision: int = 4,
    comb_digits: int = 4,
    level: int | None = None,
    gradient: bool = False,
    finish: str = "client",
) -> np.ndarray:
    """Per-pixel bound on ``|decrypted render − render_plain|`` (see the module docstring); for a packed
    store, against ``render_plain(..., slices=True)`` (:mod:`hevr.rendering.packed.sliced`).

    ``finish``: the bound of a render with the same ``finish`` (client finishing has no
    combination-matrix or reciprocal error: :mod:`hevr.colour`).

    ``gradient``: the bound of ``hevr.render(..., gradient=True)`` against
    ``hevr.render_plain(..., gradient=True)`` (the gradient channel's quantisation).

    ``level``: the bound of ``hevr.render(..., level=)`` against ``hevr.render_plain(..., level=)``.
    ``camera`` may be a :class:`~hevr.rendering.geometry.plane.Plane`: the bound of
    :func:`hevr.render_slice` against :func:`hevr.render_slice_plain` (same formula, n = the
    pixel's slab samples inside the volume); ``step`` is then ignored (it is the plane's ``slab_step``).
    """
    if getattr(getattr(ev, "meta", None), "packing", None) is not None:  # a packed store: slice-sampled frames
        has = ev.meta.gradient if gradient else ev.meta.vector
        if (gradient and mode == "xray") or (mode != "xray" and (has is None or isinstance(camera, Plane))):
            raise ParameterError(
                f"mode: expected an X-ray for a packed store (or 'emphasize' / 'tf' of a frame of one "
                f"with the vector channel, or gradient=True with the gradient channel), got "
                f"mode={mode!r}, gradient={gradient!r}"
            )
        if isinstance(camera, Plane):  # a packed store's slice (hevr.rendering.packed.planes)
            if level:
                raise ParameterError(
                    f"level: expected None for a hevr.Plane (render_slice has no level), got {level!r}"
                )
            return packed_slice_error_bound(ev.meta, camera, sampling)
        ev, camera = at_level(ev, camera, level)  # a level the owner encrypted packed: its own slots and exponent
        return packed_error_bound(ev.meta, camera, sampling, mode=mode, density=density, nodes=nodes)
    if isinstance(camera, Plane):
        step = camera.slab_step
        if level:
            raise ParameterError(f"level: expected None for a hevr.Plane (render_slice has no level), got {level!r}")
    spec, digits, precision, comb_digits = check_request(
        ev,
        camera,
        mode,
        sampling,
        step,
        density,
        nodes,
        digits,
        precision,
        comb_digits,
        (Camera, Plane),
        gradient,
        finish,
    )
    ev, camera = at_level(ev, camera, level)
    spec = level_step(spec, ev, camera)
    # a level's values are exact means of level-0 values: their storage error is level 0's
    stored = ev.base if ev.level and ev.base is not None else ev.meta
    checked = check_render_size(camera, ev.shape, ev.spacing, spec.step)
    rays = checked if checked is not None else cast_rays(camera, ev.shape, ev.spacing, spec.step)
    n = rays.n_samples.astype(np.float64).reshape(camera.height, camera.width)
    if spec.channel == "scalar":
        qmax = max(abs(ev.value_range[0]), abs(ev.value_range[1]))
        scalar = stored.scalar
        assert scalar is not None  # check_request: an X-ray reads the scalar channel
        store = 0.5 * 10.0**scalar.exponent if scalar.digits is not None else 0.0
        comb_err = 0.0
    else:
        dims = ev.vector_dims
        assert dims is not None  # check_request: emphasis and transfer functions read the vector channel
        M = combination_matrix(spec, dims)
        qmax = float(np.abs(M).sum(axis=0).max())
        store = 0.5 * 10.0 ** getattr(stored, spec.channel).exponent * qmax  # vector or gradient
        comb_err = 0.5 * 10.0**-comb_digits * np.sqrt(dims) if finish == "server" else 0.0
    K = spec.n_nodes
    weights = 4 * 10.0**-digits * (qmax + store + comb_err) if spec.sampling == "trilinear" else 0.0
    value = (qmax + store + comb_err) / K
    norm = value * 0.5 * 10.0**-precision * 1.0001 if finish == "server" else 0.0
    b = (weights / K + store / K + comb_err / K + norm) * (n > 0) + 1e-9
    return np.repeat(b[..., None], spec.channels, axis=2) if spec.channels > 1 else b
