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

import numbers
import re
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import ImageColor

from .._validate import check_choice, check_step, check_vector_dims
from ..errors import ParameterError
from ..volume.density import encode_density

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

# CSS Color Module values (so "green" and "purple" are the half-intensity CSS colours;
# "lime" is pure green).
CSS_COLORS: dict[str, tuple[float, float, float]] = {
    "black": (0.0, 0.0, 0.0),
    "white": (1.0, 1.0, 1.0),
    "red": (1.0, 0.0, 0.0),
    "lime": (0.0, 1.0, 0.0),
    "green": (0.0, 128 / 255, 0.0),
    "blue": (0.0, 0.0, 1.0),
    "yellow": (1.0, 1.0, 0.0),
    "cyan": (0.0, 1.0, 1.0),
    "magenta": (1.0, 0.0, 1.0),
    "purple": (128 / 255, 0.0, 128 / 255),
    "orange": (1.0, 165 / 255, 0.0),
    "gray": (128 / 255, 128 / 255, 128 / 255),
}

_HEX = re.compile(r"^#([0-9a-fA-F]{6}|[0-9a-fA-F]{3})$")


def parse_color(c: Any) -> tuple[float, float, float]:
    """Parse a colour: (r, g, b) floats in [0, 1], ``'#rrggbb'``/``'#rgb'`` or a CSS name
    (any of the ~150 names of Pillow's ``ImageColor`` table; :data:`CSS_COLORS` lists the
    common ones, with the same values).

    Examples
    --------
    >>> parse_color("#ff8000")
    (1.0, 0.5019607843137255, 0.0)
    >>> parse_color("Red"), parse_color((0, 0, 1)), parse_color("#00f")
    ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0))
    >>> parse_color("steelblue")
    (0.27450980392156865, 0.5098039215686274, 0.7058823529411765)
    """
    if isinstance(c, str):
        text = c.strip()
        m = _HEX.match(text)
        if m:
            h = m.group(1)
            if len(h) == 3:
                h = "".join(ch * 2 for ch in h)
            return tuple(int(h[i:i + 2], 16) / 255 for i in (0, 2, 4))  # type: ignore[return-value]
        name = text.lower()
        if name in CSS_COLORS:
            return CSS_COLORS[name]
        if name in ImageColor.colormap:
            return tuple(v / 255 for v in ImageColor.getrgb(name)[:3])  # type: ignore[return-value]
        raise ParameterError(
            f"color: expected (r, g, b) in [0, 1], '#rgb', '#rrggbb' or a CSS colour name (one of "
            f"{len(ImageColor.colormap)}, e.g. {', '.join(sorted(CSS_COLORS)[:6])}, steelblue), got {c!r}"
        )
    try:
        vals = [x for x in c]
    except TypeError:
        vals = []
    if len(vals) != 3 or any(isinstance(x, bool) or not isinstance(x, numbers.Real) for x in vals):
        raise ParameterError(
            f"color: expected (r, g, b) in [0, 1], '#rrggbb' or a CSS name, got {c!r}"
        )
    rgb = tuple(float(x) + 0.0 for x in vals)
    if not all(0.0 <= x <= 1.0 for x in rgb):  # also rejects NaN
        raise ParameterError(f"color: expected components in [0, 1], got {c!r}")
    return rgb  # type: ignore[return-value]


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


def _unit_density(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0.0 <= float(value) <= 1.0:
        raise ParameterError(f"{name}: expected a normalised density in [0, 1], got {value!r}")
    return float(value) + 0.0


def _parse_nodes(nodes: Any) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    if nodes is None:
        raise ParameterError(
            "nodes: expected a list of (density, color) pairs for mode='tf', got None"
        )
    try:
        items = list(nodes)
    except TypeError:
        raise ParameterError(f"nodes: expected a list of (density, color) pairs, got {nodes!r}") from None
    if not items:
        raise ParameterError("nodes: expected at least one (density, color) pair, got none")
    out = []
    for i, node in enumerate(items):
        try:
            d, col = node
        except (TypeError, ValueError):
            raise ParameterError(f"nodes[{i}]: expected a (density, color) pair, got {node!r}") from None
        density = _unit_density(f"nodes[{i}] density", d)
        try:
            out.append((density, parse_color(col)))
        except ParameterError as exc:
            raise ParameterError(f"nodes[{i}]: {exc}") from None
    seen: dict[float, int] = {}
    for i, (d, _) in enumerate(out):
        if d in seen:
            raise ParameterError(f"nodes: expected distinct densities, got {d:g} twice (nodes[{seen[d]}] and "
                                 f"nodes[{i}]); give each density one colour")
        seen[d] = i
    return tuple(out)


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
    >>> make_spec("xray", "nearest", 1.0, None, None, None, gradient=True)
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: gradient: expected mode 'emphasize' or 'tf' with gradient=True (the gradient channel weights the density encoding; an X-ray has none), got mode='xray'
    """
    check_choice("mode", mode, MODES)
    check_choice("sampling", sampling, SAMPLINGS)
    step = check_step(step)
    if not isinstance(gradient, (bool, np.bool_)):
        raise ParameterError(f"gradient: expected True or False, got {gradient!r}")
    gradient = bool(gradient)
    if gradient and mode not in ("emphasize", "tf"):
        raise ParameterError(f"gradient: expected mode 'emphasize' or 'tf' with gradient=True (the gradient channel "
                             f"weights the density encoding; an X-ray has none), got mode={mode!r}")
    if gradient and not has_gradient:
        raise ParameterError(
            "gradient: expected a store encrypted with gradient=True (its 'gradient' channel), got one without — "
            "encrypt again with hevr.encrypt_volume(..., vector_dims=k, gradient=True)")
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
        return RenderSpec(mode, sampling, step, density=_unit_density("density", density), gradient=gradient)
    return RenderSpec(mode, sampling, step, nodes=_parse_nodes(nodes), gradient=gradient)


def combination_matrix(spec: RenderSpec, vector_dims: int) -> np.ndarray:
    """The plaintext (k, C) matrix turning a sampled encoded vector into the mode's value.

    ``emphasize``: C = 1, the column ``e(density)``. ``tf``: C = 3,
    ``M = sum_i e(d_i) c_i^T``. (``xray`` uses the scalar channel and has none.) The same
    matrix serves the gradient channel, whose samples are g·e(d).

    Examples
    --------
    >>> spec = make_spec("tf", "nearest", 1.0, None, [(0.0, "red"), (1.0, "blue")], 2)
    >>> combination_matrix(spec, 2).tolist()
    [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    if spec.mode == "emphasize":
        return encode_density(spec.density, vector_dims).reshape(vector_dims, 1)
    if spec.mode == "tf":
        assert spec.nodes is not None
        dens = np.array([d for d, _ in spec.nodes], dtype=np.float64)
        cols = np.array([c for _, c in spec.nodes], dtype=np.float64)
        return encode_density(dens, vector_dims).T @ cols
    raise ParameterError(
        f"spec.mode: expected 'emphasize' or 'tf' (xray reads the scalar channel), got {spec.mode!r}"
    )


def normalisation_factor(spec: RenderSpec) -> int:
    """Extra per-pixel divisor: 1 for xray/emphasize, K (number of nodes) for tf.

    A pixel's value is its sum over samples divided by ``n_samples * factor``.

    Examples
    --------
    >>> normalisation_factor(make_spec("xray", "nearest", 1.0, None, None, None))
    1
    """
    return spec.n_nodes

