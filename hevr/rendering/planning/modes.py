"""Render modes and their validation, shared by the plaintext and the encrypted renderer.

Modes (API.md): ``xray`` averages the scalar channel; ``emphasize`` averages
``dot(s, e(density))`` of the sampled encoded vector ``s``; ``tf`` averages
``sum_i dot(s, e(d_i)) * c_i`` over K nodes and divides by K as well. Both vector modes
are linear in ``s``, so a renderer applies one plaintext matrix per sample:
``s @ combination_matrix(spec, k)``, and divides each pixel's sum by
``n * normalisation_factor(spec)``.

``gradient=True`` (emphasize and tf only) samples the gradient channel ``g·e(d)``
(:mod:`hevr.volume.gradient`) instead of ``e(d)``: the same matrix and kernel, each sample
weighted by its voxel's normalised gradient magnitude ``g`` (boundaries emphasised). The one
place that says which stored channel a request reads is :attr:`RenderSpec.channel`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...colour import CSS_COLORS, Colouring, parse_color, parse_nodes, unit_density
from ...core.validate import check_choice, check_step, check_vector_dims
from ...errors import ParameterError

__all__ = [
    "MODES",
    "SAMPLINGS",
    "CSS_COLORS",
    "RenderSpec",
    "parse_color",
    "make_spec",
    "combination_matrix",
    "normalisation_factor",
]

MODES = ("xray", "emphasize", "tf")
SAMPLINGS = ("nearest", "trilinear")


@dataclass(frozen=True)
class RenderSpec:
    """A validated render request (hashable, usable as a cache key).

    Attributes
    ----------
    mode : {'xray', 'emphasize', 'tf'}
    sampling : {'nearest', 'trilinear'}
    step : float
    density : float or None
        Only for ``emphasize`` (``None`` otherwise).
    nodes : tuple of (float, (r, g, b)) or None
        Only for ``tf`` (``None`` otherwise), in the order given.
    gradient : bool
        Sample the gradient channel g·e(d) instead of e(d) (``emphasize``, ``tf`` only).
    """

    mode: str
    sampling: str
    step: float
    density: float | None = None
    nodes: tuple[tuple[float, tuple[float, float, float]], ...] | None = None
    gradient: bool = False

    @property
    def channels(self) -> int:
        """Image channels: 3 for ``tf``, else 1."""
        return 3 if self.mode == "tf" else 1

    @property
    def needs_vector(self) -> bool:
        """Whether the mode reads the encoded-vector channel (emphasize, tf)."""
        return self.mode != "xray"

    @property
    def channel(self) -> str:
        """The stored channel the request reads: ``"scalar"`` (xray), ``"vector"``, or
        ``"gradient"`` (emphasize / tf with ``gradient=True``).

        >>> RenderSpec("tf", "nearest", 1.0, gradient=True).channel
        'gradient'
        """
        if not self.needs_vector:
            return "scalar"
        return "gradient" if self.gradient else "vector"

    @property
    def n_nodes(self) -> int:
        """K, the number of transfer-function nodes (``tf``), else 1: the extra divisor."""
        return len(self.nodes) if self.mode == "tf" and self.nodes else 1

    def image_shape(self, height: int, width: int) -> tuple[int, ...]:
        """The rendered image's shape: (height, width), or (height, width, 3) for ``tf``.

        >>> RenderSpec("tf", "nearest", 1.0).image_shape(2, 3)
        (2, 3, 3)
        """
        return (int(height), int(width)) + ((self.channels,) if self.channels > 1 else ())


def make_spec(
    mode: str,
    sampling: str,
    step: float,
    density: float | None,
    nodes: Any,
    vector_dims: int | None,
    has_scalar: bool = True,
    gradient: Any = False,
    has_gradient: bool = False,
) -> RenderSpec:
    """Validate a render request against what the volume/store holds.

    Parameters
    ----------
    mode, sampling, step, density, nodes :
        As for ``hevr.render``; ``density``/``nodes`` are ignored (stored as ``None``)
        by modes that do not use them.
    vector_dims : int or None
        Length of the volume's encoded-vector channel, ``None`` if it has none.
    has_scalar : bool
        Whether the volume has the scalar channel (needed by ``xray``).
    gradient : bool
        Read the gradient channel (``emphasize`` / ``tf`` only).
    has_gradient : bool
        Whether the volume has the gradient channel (needed by ``gradient=True``).

    Examples
    --------
    >>> make_spec("emphasize", "nearest", 1.0, 0.653, None, vector_dims=4).density
    0.653
    >>> make_spec("xray", "nearest", 1.0, None, None, None, gradient=True)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: gradient: expected mode 'emphasize' or 'tf' with gradient=True (...), got mode='xray'
    """
    check_choice("mode", mode, MODES)
    check_choice("sampling", sampling, SAMPLINGS)
    step = check_step(step)
    if not isinstance(gradient, (bool, np.bool_)):
        raise ParameterError(f"gradient: expected True or False, got {gradient!r}")
    gradient = bool(gradient)
    if gradient and mode not in ("emphasize", "tf"):
        raise ParameterError(
            f"gradient: expected mode 'emphasize' or 'tf' with gradient=True (the gradient channel "
            f"weights the density encoding; an X-ray has none), got mode={mode!r}"
        )
    if gradient and not has_gradient:
        raise ParameterError(
            "gradient: expected a store encrypted with gradient=True (its 'gradient' channel), got one without — "
            "encrypt again with hevr.encrypt_volume(..., vector_dims=k, gradient=True)"
        )
    if mode == "xray":
        if not has_scalar:
            raise ParameterError(
                "mode: 'xray' needs the scalar channel, but the store/volume has none "
                "(re-encrypt with scalar=True), got mode='xray'"
            )
        return RenderSpec(mode, sampling, step)
    if vector_dims is None:
        raise ParameterError(
            f"mode: {mode!r} needs the encoded-density vector channel, but the store/volume "
            f"has no vector channel (re-encrypt with vector_dims=k, e.g. 4), got vector_dims=None"
        )
    check_vector_dims(vector_dims)
    if mode == "emphasize":
        if density is None:
            raise ParameterError("density: expected a density in [0, 1] for mode='emphasize', got None")
        return RenderSpec(mode, sampling, step, density=unit_density("density", density), gradient=gradient)
    return RenderSpec(mode, sampling, step, nodes=parse_nodes(nodes), gradient=gradient)


def combination_matrix(spec: RenderSpec, vector_dims: int) -> np.ndarray:
    """The plaintext (k, C) matrix turning a sampled encoded vector into the mode's value:
    :meth:`hevr.colour.Colouring.matrix` of the spec's colouring (one home for the maths).

    ``emphasize``: C = 1, the column ``e(density)``. ``tf``: C = 3,
    ``M = sum_i e(d_i) c_i^T``. (``xray`` uses the scalar channel and has none.) The same
    matrix serves the gradient channel, whose samples are g·e(d).

    Examples
    --------
    >>> spec = make_spec("tf", "nearest", 1.0, None, [(0.0, "red"), (1.0, "blue")], 2)
    >>> combination_matrix(spec, 2).tolist()
    [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    if spec.mode == "xray":
        raise ParameterError(
            f"spec.mode: expected 'emphasize' or 'tf' (xray reads the scalar channel), got {spec.mode!r}"
        )
    return Colouring.of(spec).matrix(vector_dims)


def normalisation_factor(spec: RenderSpec) -> int:
    """Extra per-pixel divisor: 1 for xray/emphasize, K (number of nodes) for tf.

    A pixel's value is its sum over samples divided by ``n_samples * factor``.

    Examples
    --------
    >>> normalisation_factor(make_spec("xray", "nearest", 1.0, None, None, None))
    1
    """
    return spec.n_nodes
