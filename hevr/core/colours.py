"""Colours and transfer-function nodes as the caller writes them, checked: ``(r, g, b)`` in [0, 1],
``'#rrggbb'`` / ``'#rgb'`` or a CSS colour name; a normalised density; a transfer function's
(density, colour) nodes. What :class:`hevr.Colouring` and the render modes are built from.

>>> parse_color("lime")
(0.0, 1.0, 0.0)
"""

from __future__ import annotations

import numbers
import re
from typing import Any

from PIL import ImageColor

from ..errors import ParameterError

__all__ = ["CSS_COLORS", "parse_color", "parse_nodes", "unit_density"]

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
            r, g, b = (int(h[i : i + 2], 16) / 255 for i in (0, 2, 4))
            return r, g, b
        name = text.lower()
        if name in CSS_COLORS:
            return CSS_COLORS[name]
        if name in ImageColor.colormap:
            r, g, b = (v / 255 for v in ImageColor.getrgb(name)[:3])
            return r, g, b
        raise ParameterError(
            f"color: expected (r, g, b) in [0, 1], '#rgb', '#rrggbb' or a CSS colour name (one of "
            f"{len(ImageColor.colormap)}, e.g. {', '.join(sorted(CSS_COLORS)[:6])}, steelblue), got {c!r}"
        )
    try:
        vals = [x for x in c]
    except TypeError:
        vals = []
    if len(vals) != 3 or any(isinstance(x, bool) or not isinstance(x, numbers.Real) for x in vals):
        raise ParameterError(f"color: expected (r, g, b) in [0, 1], '#rrggbb' or a CSS name, got {c!r}")
    r, g, b = (float(x) + 0.0 for x in vals)
    if not all(0.0 <= x <= 1.0 for x in (r, g, b)):  # also rejects NaN
        raise ParameterError(f"color: expected components in [0, 1], got {c!r}")
    return r, g, b


def unit_density(name: str, value: Any) -> float:
    """A normalised density in [0, 1] as a float (``name`` names it in the message).

    >>> unit_density("density", 1)
    1.0
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0.0 <= float(value) <= 1.0:
        raise ParameterError(f"{name}: expected a normalised density in [0, 1], got {value!r}")
    return float(value) + 0.0


def parse_nodes(nodes: Any) -> tuple[tuple[float, tuple[float, float, float]], ...]:
    """A transfer function's nodes: (density in [0, 1], colour) pairs with distinct densities.

    >>> parse_nodes([(0.3, "blue"), (0.8, (1, 0, 0))])
    ((0.3, (0.0, 0.0, 1.0)), (0.8, (1.0, 0.0, 0.0)))
    """
    if nodes is None:
        raise ParameterError("nodes: expected a list of (density, color) pairs for mode='tf', got None")
    try:
        items = list(nodes)
    except TypeError:
        raise ParameterError(f"nodes: expected a list of (density, color) pairs, got {nodes!r}") from None
    if not items:
        raise ParameterError("nodes: expected at least one (density, color) pair, got none")
    out: list[tuple[float, tuple[float, float, float]]] = []
    for i, node in enumerate(items):
        try:
            d, col = node
        except (TypeError, ValueError):
            raise ParameterError(f"nodes[{i}]: expected a (density, color) pair, got {node!r}") from None
        density = unit_density(f"nodes[{i}] density", d)
        try:
            out.append((density, parse_color(col)))
        except ParameterError as exc:
            raise ParameterError(f"nodes[{i}]: {exc}") from None
    seen: dict[float, int] = {}
    for i, (d, _) in enumerate(out):
        if d in seen:
            raise ParameterError(
                f"nodes: expected distinct densities, got {d:g} twice (nodes[{seen[d]}] and "
                f"nodes[{i}]); give each density one colour"
            )
        seen[d] = i
    return tuple(out)
