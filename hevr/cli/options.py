"""argparse value types of the ``hevr`` command line (:mod:`hevr.cli.main`).

Each turns a bad value into one argparse error, ``argument --bits: expected …, got '…'``
(exit 2), before anything is loaded or started; the caps (``MAX_WORKERS``, ``MAX_PHANTOM``,
``MAX_PRECISION``, the library's own limits) live here.
"""

from __future__ import annotations

import argparse
import math
import re
from typing import Sequence

from .._validate import MAX_BRICK_EDGE, MAX_STORE_DIGITS, MAX_VECTOR_DIMS
from ..crypto.keys import MAX_BITS, MIN_BITS, SECURE_BITS
from ..errors import ParameterError
from ..rendering.modes import parse_color
from ..rendering.planner import MAX_PIXELS_KEY, render_limits
from ..volume.modality import TF_PRESETS
from ..volume.pyramid import MAX_LEVELS


# -- value types ----------------------------------------------------------------
def bits_type(text: str) -> int:
    """``--bits``: an even key size in [MIN_BITS, MAX_BITS]."""
    try:
        bits = int(text)
    except ValueError:
        bits = -1
    if bits < MIN_BITS or bits > MAX_BITS or bits % 2:
        raise argparse.ArgumentTypeError(
            f"expected an even number of bits in [{MIN_BITS}, {MAX_BITS}] (e.g. {SECURE_BITS}), got {text!r}")
    return bits


def _int_at_least(lo: int, expected: str):
    """An argparse type: an integer >= ``lo``, else "expected <expected>, got '<text>'"."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            v = lo - 1
        if v < lo:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v
    return parse


# Most worker processes --workers starts on this machine (each is a Python process).
MAX_WORKERS = 1024
# Largest phantom:N / demo --size: 1024^3 voxels is 1 GiB in memory and days of encryption.
MAX_PHANTOM = 1024

positive_int = _int_at_least(1, "a positive integer")
# Most decimal digits of a render's normalisation (hevr.render's own cap).
MAX_PRECISION = 30


nonneg_int = _int_at_least(0, "a non-negative integer")


def _int_range(lo: int, hi: int, expected: str):
    """An argparse type: an integer in [lo, hi]; anything else names ``expected`` and the text."""
    def parse(text: str) -> int:
        v = _int_at_least(lo, expected)(text)
        if v > hi:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v
    return parse


# --digits: decimal digits kept of float voxels (the library's cap); --precision: of the normalisation
vector_dims_type = _int_range(2, MAX_VECTOR_DIMS, f"an integer in [2, {MAX_VECTOR_DIMS}] (the paper uses 4)")
digits_type = _int_range(0, MAX_STORE_DIGITS, f"an integer in [0, {MAX_STORE_DIGITS}]")
precision_type = _int_range(0, MAX_PRECISION, f"an integer in [0, {MAX_PRECISION}]")


def phantom_size_type(text: str) -> int:
    """A phantom edge N: an integer in [4, MAX_PHANTOM]."""
    try:
        v = int(text) if text.strip().isascii() else 0
    except ValueError:
        v = 0
    if not 4 <= v <= MAX_PHANTOM:
        raise argparse.ArgumentTypeError(f"expected a phantom edge N in [4, {MAX_PHANTOM}] voxels, got {text!r}")
    return v


workers_type = _int_range(0, MAX_WORKERS, f"at most {MAX_WORKERS} worker processes (0: none)")  # --workers


def finite_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def positive_float(text: str) -> float:
    v = finite_float(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def unit_float(text: str) -> float:
    v = finite_float(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a normalised density in [0, 1], got {text!r}")
    return v


def size_type(text: str) -> tuple[int, int]:
    """``WxH`` (or a single ``N`` for a square) -> (width, height), at most the render
    pixel limit (``hevr.limits.max-pixels``, :mod:`hevr.rendering.planner`) in all."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        vals = [int(p) for p in parts if p.strip().isascii()]
    except ValueError:
        vals = []
    if len(vals) == 1 and len(parts) == 1:
        vals = vals * 2
    if len(vals) != 2 or len(parts) > 2 or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels such as 150x150, got {text!r}")
    max_pixels = render_limits()[0]
    if vals[0] * vals[1] > max_pixels:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT of at most {max_pixels} pixels in all "
                                         f"(Dask config {MAX_PIXELS_KEY}), got {text!r} = "
                                         f"{vals[0] * vals[1]} pixels")
    return vals[0], vals[1]


def floats_type(count: int, what: str, positive: bool = False):
    """A comma-separated list of exactly ``count`` finite floats."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            vals = tuple(float(p) for p in text.split(","))
        except ValueError:
            vals = ()
        if len(vals) != count or not all(math.isfinite(v) and (v > 0 or not positive) for v in vals):
            kind = "positive " if positive else ""
            raise argparse.ArgumentTypeError(f"expected {what}: {count} comma-separated {kind}numbers, got {text!r}")
        return vals

    return parse


def range_type(text: str) -> tuple[float, float]:
    lo, hi = floats_type(2, "LO,HI")(text)
    if not hi > lo:
        raise argparse.ArgumentTypeError(f"expected LO,HI with HI > LO, got {text!r}")
    return lo, hi


def brick_type(text: str) -> int | tuple[int, int, int]:
    """``--brick 32`` or ``--brick BZ,BY,BX``."""
    try:
        vals = [int(p) for p in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, 3) or min(vals, default=0) < 1:
        raise argparse.ArgumentTypeError(f"expected a positive brick edge N or BZ,BY,BX, got {text!r}")
    if max(vals) > MAX_BRICK_EDGE:
        raise argparse.ArgumentTypeError(f"expected a brick edge of at most {MAX_BRICK_EDGE} voxels, got {text!r}")
    return vals[0] if len(vals) == 1 else (vals[0], vals[1], vals[2])


def parse_tf(text: str) -> list[tuple[float, tuple[float, float, float]]]:
    """``"0.279:#0000ff,0.797:red"`` -> [(0.279, (0, 0, 1)), (0.797, (1, 0, 0))].

    >>> parse_tf("0.5:#f00, 1:blue")
    [(0.5, (1.0, 0.0, 0.0)), (1.0, (0.0, 0.0, 1.0))]
    """

    nodes: list[tuple[float, tuple[float, float, float]]] = []
    for i, item in enumerate(p.strip() for p in text.split(",")):
        dens, sep, col = item.partition(":")
        if not sep:
            raise ParameterError(f"transfer-function node {i + 1} {item!r}: expected DENSITY:COLOR such as 0.279:blue")
        try:
            d = float(dens)
        except ValueError:
            d = math.nan
        if not 0.0 <= d <= 1.0:
            raise ParameterError(f"transfer-function node {i + 1} {item!r}: density must be a number in [0, 1]")
        twin = next((j for j, (dj, _) in enumerate(nodes) if dj == d), None)
        if twin is not None:
            raise ParameterError(f"transfer-function node {i + 1} {item!r}: density {d:g} is node {twin + 1}'s "
                                 "as well; give each density one colour")
        try:
            nodes.append((d, parse_color(col.strip())))
        except ParameterError:
            raise ParameterError(f"transfer-function node {i + 1} {item!r}: unknown colour {col.strip()!r} "
                                 "(use #rrggbb, #rgb or a CSS name such as red, blue, green)") from None
    return nodes


def tf_type(text: str) -> list[tuple[float, tuple[float, float, float]]] | str:
    """``--tf``: nodes, or a preset name (:data:`hevr.TF_PRESETS`) kept as the name: the command
    turns it into nodes with the store's value range (:func:`hevr.cli.scan.resolve_tf`).

    >>> tf_type("CT-Bone"), tf_type("0.5:red")
    ('ct-bone', [(0.5, (1.0, 0.0, 0.0))])
    """
    if text.strip().lower() in TF_PRESETS:
        return text.strip().lower()
    if ":" not in text:
        raise argparse.ArgumentTypeError(f"expected a preset ({', '.join(TF_PRESETS)}) or DENSITY:COLOR,... "
                                         f"such as 0.279:blue, got {text!r}")
    try:
        return parse_tf(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


level_type = _int_range(0, MAX_LEVELS, f"a pyramid level from 0 to {MAX_LEVELS}")  # --level L (0: the volume)
levels_type = _int_range(1, MAX_LEVELS, f"a number of levels from 1 to {MAX_LEVELS}")  # --levels N to build


NEGATIVE_VALUE = re.compile(r"^-[\d.]")  # "-5x-5", "-1024,3071", "-.5": a value, never an option name


def value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string of ``parser`` and its subcommands that takes exactly one value."""
    out: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out |= value_options(sub)
        elif action.option_strings and action.nargs is None:
            out.update(action.option_strings)
    return out


def join_negative_values(argv: Sequence[str], options: set[str]) -> list[str]:
    """``--size -5x-5`` → ``--size=-5x-5`` for ``options`` that take a value: argparse reads a
    following token that starts with ``-`` as an option unless it is a plain negative number, and
    would say "expected one argument"; joined, the option's own check names what is wrong.

    >>> join_negative_values(["render", "--size", "-5x-5", "--azimuth", "-30", "-q"], {"--size", "--azimuth"})
    ['render', '--size=-5x-5', '--azimuth=-30', '-q']
    """
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = str(argv[i])
        if a in options and i + 1 < len(argv) and NEGATIVE_VALUE.match(str(argv[i + 1])):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out
