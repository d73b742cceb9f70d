"""A render request, checked once where it enters (:func:`hevr.render`, :func:`hevr.render_slice`,
:func:`hevr.render_frame`, :func:`hevr.error_bound`), and the view moved to a pyramid level.

The checked :class:`~hevr.rendering.planning.modes.RenderSpec` is passed inward; nothing below asks
the user's arguments again.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..._validate import check_choice, check_int
from ...errors import ParameterError
from ...image.checks import FINISHES
from ...store.reader import EncryptedVolume
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from .modes import RenderSpec, make_spec

__all__ = ["FINISHES", "at_level", "check_request", "level_step"]


def check_request(ev: Any, camera: Any, mode: Any, sampling: Any, step: Any, density: Any, nodes: Any,
                   digits: Any, precision: Any, comb_digits: Any, views: tuple[type, ...] = (Camera,),
                   gradient: Any = False, finish: Any = "client") -> tuple[RenderSpec, int, int, int]:
    """Check what :func:`render` and :func:`error_bound` share, once, where it enters (``views``:
    the kinds of view the caller takes)."""
    if not isinstance(ev, EncryptedVolume):
        raise ParameterError(f"ev: expected an EncryptedVolume (hevr.open_volume), got {type(ev).__name__}")
    if not isinstance(camera, views):
        kinds = " or ".join(f"hevr.{v.__name__}" for v in views)
        raise ParameterError(f"camera: expected a {kinds}, got {type(camera).__name__}")
    spec = make_spec(mode, sampling, step, density, nodes, ev.vector_dims, ev.has_scalar, gradient, ev.has_gradient)
    check_choice("finish", finish, FINISHES)
    return (spec, check_int("digits", digits, 0, 9), check_int("precision", precision, 0, 30),
            check_int("comb_digits", comb_digits, 1, 12))


def at_level(ev: EncryptedVolume, view: Camera | Plane, level: int | None) -> tuple[EncryptedVolume, Camera | Plane]:
    """The volume to render — ``ev``, or the pyramid level asked for — and the view moved into
    that level's frame: a level's voxel (0, 0, 0) sits at ``ev.origin``, hevr's rays assume
    the origin, so the view moves by ``−origin`` (an exact change of coordinates)."""
    if level is not None and level != ev.level:
        ev = ev.at_level(level)
    if not ev.level:
        return ev, view
    shift = np.asarray(ev.origin)
    if isinstance(view, Plane):
        return ev, dataclasses.replace(view, origin=tuple((np.asarray(view.origin) - shift).tolist()))
    return ev, dataclasses.replace(view, position=tuple((np.asarray(view.position) - shift).tolist()),
                                   focal_point=tuple((np.asarray(view.focal_point) - shift).tolist()))


def level_step(spec: RenderSpec, ev: EncryptedVolume, view: Camera | Plane) -> RenderSpec:
    """A level is sampled in its own voxels: ``step`` (world units at level 0) becomes
    ``step·2^level``, so a coarse frame takes 2^level times fewer samples per ray instead of
    revisiting each coarse voxel 2^level times (a plane keeps its slab step)."""
    if not ev.level or isinstance(view, Plane):
        return spec
    return dataclasses.replace(spec, step=spec.step * 2**ev.level)
