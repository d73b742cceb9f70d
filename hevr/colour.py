"""Colour on the client: a decrypted frame of component ray sums, and its colouring in numpy.

A render finished on the client (``hevr.render(..., finish="client")``, the default) leaves the
server with nothing but the per-component ray sums of the stored channel: for a ray r with
n_r samples (public: camera and volume shape) and weights w_{r,s}, the stored mantissas
q_{v,k} of component k give

    S_{r,k} = Σ_s Σ_v w_{r,s,v}·q_{v,k}          (exact integers; packed by the server)

and the client decrypts S and computes, in float64,

    x_{r,k} = S_{r,k}·10^e / n_r                  (e: the weight and channel exponents)

— the ray's mean of each stored component, divided by the public sample count exactly (no
fixed-point reciprocal). Every mode is then a linear map of these means with coefficients the
client alone knows (:func:`colour`):

* ``xray`` (scalar channel, K = 1): value = x_{r,1};
* ``emphasize``: value = Σ_k x_{r,k}·e(d)_k, e the density encoding (Alg. 4);
* ``tf`` with nodes (d_i, c_i), i = 1..N: colour = (1/N)·Σ_k x_{r,k}·M_{k,:},
  M = Σ_i e(d_i)·c_i^T (:meth:`Colouring.matrix`);
* ``gradient=True`` renders read the gradient channel g·e(d) and colour the same way.

Error bound against :func:`hevr.render_plain` (same view): only the stored quantisation and, for
trilinear sampling, the weights' rounding remain — no combination-matrix rounding, no reciprocal:
|err| <= (4·10^-digits·(qmax + store)·[trilinear] + store)/N + 1e-9 per pixel, where qmax is
the largest |value| a sample can take, store = 0.5·10^exponent_of_the_channel·qmax
(:func:`hevr.error_bound` with ``finish="client"``). The float64 arithmetic adds a relative
error of a few 10^-16.

Re-colouring (:meth:`Frame.recolour`) is one (H·W, K) × (K, C) product: milliseconds, no cluster.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import numpy as np

from .core.colours import CSS_COLORS, parse_color, parse_nodes, unit_density
from .core.validate import check_choice
from .errors import ParameterError
from .volume.density import encode_density

__all__ = [
    "CSS_COLORS",
    "Colouring",
    "Frame",
    "colour",
    "colouring_spec",
    "frame_from_sums",
    "parse_color",
    "parse_nodes",
    "scaled_sums",
    "unit_density",
]

MODES = ("xray", "emphasize", "tf")


@dataclass(frozen=True)
class Colouring:
    """How a pixel's mean stored components become its value: the client's half of a render
    request (frozen, validated; never sent to the server when finished on the client).

    Attributes
    ----------
    mode : {"xray", "emphasize", "tf"}
    density : float or None
        The emphasised normalised density (``emphasize`` only).
    nodes : tuple of (density, (r, g, b)) or None
        The transfer function (``tf`` only), in the order given; colours as :func:`parse_color`.

    Examples
    --------
    >>> Colouring("tf", nodes=[(0.0, "red"), (1.0, "blue")]).matrix(2).tolist()
    [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    >>> Colouring("emphasize")
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: density: expected a density in [0, 1] for mode='emphasize', got None
    """

    mode: str
    density: float | None = None
    nodes: Any = None

    def __post_init__(self) -> None:
        check_choice("mode", self.mode, MODES)
        if self.mode == "emphasize":
            if self.density is None:
                raise ParameterError("density: expected a density in [0, 1] for mode='emphasize', got None")
            object.__setattr__(self, "density", unit_density("density", self.density))
        else:
            object.__setattr__(self, "density", None)
        object.__setattr__(self, "nodes", parse_nodes(self.nodes) if self.mode == "tf" else None)

    @classmethod
    def of(cls, spec: Any) -> Colouring:
        """The colouring of a :class:`~hevr.rendering.planning.modes.RenderSpec` (or anything with
        ``mode``, ``density`` and ``nodes``)."""
        return cls(spec.mode, spec.density, spec.nodes)

    @property
    def n_nodes(self) -> int:
        """N, the transfer function's nodes (its extra divisor), else 1."""
        return len(self.nodes) if self.nodes else 1

    @property
    def channels(self) -> int:
        return 3 if self.mode == "tf" else 1

    def matrix(self, k: int) -> np.ndarray:
        """The (k, C) matrix of the mode on a k-dim density encoding: ``e(density)`` as a column
        (emphasize), ``Σ_i e(d_i)·c_i^T`` (tf); module docstring."""
        if self.mode == "emphasize":
            return encode_density(self.density, k).reshape(k, 1)
        if self.mode == "tf":
            dens = np.array([d for d, _ in self.nodes], dtype=np.float64)
            cols = np.array([c for _, c in self.nodes], dtype=np.float64)
            return encode_density(dens, k).T @ cols
        raise ParameterError(
            "mode: expected 'emphasize' or 'tf' for a combination matrix (an X-ray has none), got 'xray'"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "density": self.density,
            "nodes": [[d, list(c)] for d, c in self.nodes] if self.nodes else None,
        }

    @classmethod
    def from_dict(cls, d: Any) -> Colouring:
        if not isinstance(d, dict) or set(d) - {"mode", "density", "nodes"} or "mode" not in d:
            raise ParameterError(f"colouring: expected a dict with mode, density and nodes, got {d!r:.80}")
        return cls(d["mode"], d.get("density"), d.get("nodes"))

    def key(self) -> tuple[Any, ...]:
        return (self.mode, self.density, self.nodes)


def colouring_spec(
    channel: str,
    components: int,
    mode: Any = None,
    density: Any = None,
    nodes: Any = None,
    default: Colouring | None = None,
) -> Colouring:
    """The checked colouring of a frame of ``channel``'s sums (``components`` per pixel): the
    arguments when any is given (``nodes`` alone means ``mode="tf"``, ``density`` alone
    ``"emphasize"``), else ``default`` (the render's own), else X-ray for the scalar channel.

    >>> colouring_spec("vector", 4, nodes=[(0.5, "red")]).mode
    'tf'
    >>> colouring_spec("vector", 4)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    hevr.errors.ParameterError: nodes: expected a transfer function (...) or an emphasised density ..., got neither
    """
    if mode is None and density is None and nodes is None:
        if default is not None:
            return default
        if channel == "scalar":
            mode = "xray"
        else:
            raise ParameterError(
                f"nodes: expected a transfer function (nodes=[(density, colour), ...]) or an emphasised density "
                f"(density=...) to colour a frame of the {channel} channel's ray sums, got neither"
            )
    if mode is None:
        mode = "tf" if nodes is not None else "emphasize"
    check_choice("mode", mode, MODES)
    if channel == "scalar" and mode != "xray":
        raise ParameterError(
            f"mode: expected 'xray' for a frame of the scalar channel's ray sums, got {mode!r} "
            "(emphasis and transfer functions colour the vector channel: render mode='tf')"
        )
    if channel != "scalar" and mode == "xray":
        raise ParameterError(
            f"mode: expected 'emphasize' or 'tf' for a frame of the {channel} channel's ray sums, "
            "got 'xray' (an X-ray reads the scalar channel: render mode='xray')"
        )
    return Colouring(mode, density, nodes)


def colour(means: np.ndarray, colouring: Colouring) -> np.ndarray:
    """The image of per-pixel component means ``means`` (H, W, K) under ``colouring`` (module
    docstring): (H, W) for xray / emphasize, (H, W, 3) for tf.

    >>> m = np.zeros((1, 2, 2)); m[0, 0] = (1.0, 0.0)
    >>> colour(m, Colouring("tf", nodes=[(0.0, "red"), (1.0, "blue")])).tolist()
    [[[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]]]
    """
    if colouring.mode == "xray":
        return np.array(means[..., 0], dtype=np.float64)
    out = means @ (colouring.matrix(means.shape[-1]) / colouring.n_nodes)
    return out[..., 0] if colouring.mode == "emphasize" else out


@dataclass(frozen=True, eq=False)
class Frame:
    """A decrypted frame of component ray sums, on the client: colour it any number of times.

    From :meth:`hevr.EncryptedImage.decrypt_frame` or :func:`hevr.render_frame`.

    Attributes
    ----------
    means : np.ndarray, (H, W, K) float64
        Per pixel, the mean over its samples of each stored component (0 where the ray misses).
    n_samples : np.ndarray, (H, W) int64
        Samples per pixel (public geometry).
    channel : str
        The stored channel rendered: ``"scalar"``, ``"vector"`` or ``"gradient"``.
    colouring : Colouring or None
        The render's own colouring (client-side only; never stored), used when
        :meth:`recolour` is given none.
    stats : dict
        ``seconds`` (end to end: request to decrypted means, where known), ``decrypt_s``,
        ``ciphertexts`` and the render's stats.
    """

    means: np.ndarray
    n_samples: np.ndarray
    channel: str
    colouring: Colouring | None = field(default=None, repr=False)
    stats: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:  # never the pixels, never the colouring
        H, W, K = self.means.shape
        return f"Frame({H}x{W}, channel={self.channel!r}, components={K})"

    @property
    def components(self) -> int:
        return int(self.means.shape[-1])

    def spec(self, mode: Any = None, density: Any = None, nodes: Any = None) -> Colouring:
        """The checked colouring :meth:`recolour` would apply (:func:`colouring_spec`)."""
        return colouring_spec(self.channel, self.components, mode, density, nodes, self.colouring)

    def recolour(self, mode: str | None = None, density: float | None = None, nodes: Any = None) -> np.ndarray:
        """The frame's image under another colouring (or its own when none is given): a numpy
        product of milliseconds, on this machine; nothing is sent anywhere.

        Parameters
        ----------
        mode : {"xray", "emphasize", "tf"}, optional
            Default: ``"tf"`` when ``nodes`` is given, ``"emphasize"`` when ``density`` is.
        density, nodes
            As for :func:`hevr.render`.

        Returns
        -------
        np.ndarray
            (H, W) or (H, W, 3) float64, within :func:`hevr.error_bound` (``finish="client"``)
            of :func:`hevr.render_plain` with the same parameters.
        """
        return colour(self.means, self.spec(mode, density, nodes))

    @property
    def image(self) -> np.ndarray:
        """The frame under its render's colouring (:meth:`recolour` with no arguments)."""
        return self.recolour()


def scaled_sums(values: list[int], exponent: int) -> np.ndarray:
    """The decrypted integer sums ``values`` (offset removed) times 10^exponent, as float64: one
    rounding (10^k is exact in float64 for k <= 22) — or, for sums beyond float64 or exponents
    below -300, exactly rounded through fractions (the planner only promises that the scaled
    values fit: :func:`hevr.core.limits.fits_float`).

    >>> scaled_sums([12345, -5], -3).tolist(), scaled_sums([10**400], -398).tolist()
    ([12.345, -0.005], [100.0])
    """
    e = int(exponent)
    if e >= -300:
        try:
            S = np.array(values, dtype=np.float64)
        except OverflowError:  # a sum beyond float64 whose scaled value fits
            pass
        else:
            return S / 10.0**-e if -22 <= e < 0 else S * 10.0**e
    scale = Fraction(10) ** e
    return np.array([float(v * scale) for v in values], dtype=np.float64)


def frame_from_sums(
    scaled: np.ndarray,
    n_samples: np.ndarray,
    channel: str,
    colouring: Colouring | None,
    stats: dict[str, Any],
    t0: float | None = None,
) -> Frame:
    """A :class:`Frame` from the scaled sums S·10^exponent (H, W, K) (:func:`scaled_sums`) and
    the public sample counts: x = S·10^exponent / n (module docstring)."""
    t = time.perf_counter()
    n = np.asarray(n_samples, dtype=np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(n[..., None] > 0, scaled / np.maximum(n, 1)[..., None], 0.0)
    stats = dict(stats, convert_s=time.perf_counter() - t)
    if t0 is not None:
        stats["seconds"] = time.perf_counter() - t0
    return Frame(means=means, n_samples=n, channel=channel, colouring=colouring, stats=stats)
