"""argparse types and options of the ``hevr`` command line that quote the render side's tables:
image sizes (the render pixel limit), colours and transfer functions (presets), pyramid levels,
views, modalities and planes, the colouring options of render, recolour, slice and decrypt, and
``--server``. The verification options are in :mod:`hevr.cli.verify_options`.

Apart from :mod:`hevr.cli.options` because of what they import: :mod:`hevr.colour`,
:mod:`hevr.volume` and the render limits (Dask's configuration). Only the commands that take
these options build their parser from here (:mod:`hevr.cli.render_arguments`); ``hevr
--version``, ``hevr --help`` and ``hevr info KEY`` never import it.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from ..colour import parse_color
from ..core.limits import MAX_PIXELS_KEY, render_limits
from ..errors import ParameterError
from ..rendering.geometry.views import VIEWS
from ..volume.modality import MODALITY_RANGES, TF_PRESETS, UNSUPPORTED, modality_range
from ..volume.pyramid import MAX_LEVELS
from .options import (
    add_scan_read_options,
    finite_float,
    int_range,
    range_type,
    unit_float,
)

__all__ = [
    "MODALITY_CHOICES",
    "TF_HELP",
    "add_decrypt_colour_options",
    "add_encrypt_scan_options",
    "add_finish_option",
    "add_view_option",
    "format_tf",
    "level_type",
    "levels_type",
    "modality_type",
    "oblique_type",
    "parse_tf",
    "size_type",
    "tf_type",
]

MODALITY_CHOICES = ("auto",) + tuple(MODALITY_RANGES)


# -- image sizes ------------------------------------------------------------------------------
def size_type(text: str) -> tuple[int, int]:
    """``WxH`` (or a single ``N`` for a square) -> (width, height), at most the render
    pixel limit (``hevr.limits.max-pixels``, :mod:`hevr.core.limits`) in all."""
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
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT of at most {max_pixels} pixels in all "
            f"(Dask config {MAX_PIXELS_KEY}), got {text!r} = "
            f"{vals[0] * vals[1]} pixels"
        )
    return vals[0], vals[1]


# -- colours and transfer functions -----------------------------------------------------------
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
            raise ParameterError(
                f"transfer-function node {i + 1} {item!r}: density {d:g} is node {twin + 1}'s "
                "as well; give each density one colour"
            )
        try:
            nodes.append((d, parse_color(col.strip())))
        except ParameterError:
            raise ParameterError(
                f"transfer-function node {i + 1} {item!r}: unknown colour {col.strip()!r} "
                "(use #rrggbb, #rgb or a CSS name such as red, blue, green)"
            ) from None
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
        raise argparse.ArgumentTypeError(
            f"expected a preset ({', '.join(TF_PRESETS)}) or DENSITY:COLOR,... such as 0.279:blue, got {text!r}"
        )
    try:
        return parse_tf(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def format_tf(nodes: Any) -> str:
    """Nodes (colours in any form :func:`parse_color` reads) -> ``"0.279:#0000ff,..."``.

    >>> format_tf([(0.279, "blue"), (0.797, (1, 0, 0))])
    '0.279:#0000ff,0.797:#ff0000'
    """
    out = []
    for d, c in nodes:
        rgb = "#" + "".join(f"{round(float(x) * 255):02x}" for x in parse_color(c))
        out.append(f"{float(d):g}:{rgb}")
    return ",".join(out)


TF_HELP = (
    f"transfer function: a preset ({', '.join(TF_PRESETS)}: windows in the modality's units, converted "
    "with the store's value range) or DENSITY:COLOR,... (colours #rrggbb, #rgb or CSS names)"
)


# -- pyramid levels, modalities, planes -------------------------------------------------------
level_type = int_range(0, MAX_LEVELS, f"a pyramid level from 0 to {MAX_LEVELS}")  # --level L (0: the volume)
levels_type = int_range(1, MAX_LEVELS, f"a number of levels from 1 to {MAX_LEVELS}")  # --levels N to build


def modality_type(text: str) -> str:
    """``--modality``: ``auto`` or a modality with a fixed range (upper-cased).

    >>> modality_type("ct"), modality_type("auto")
    ('CT', 'auto')
    """
    if text.strip().lower() == "auto":
        return "auto"
    try:
        modality_range(text)
    except ParameterError as exc:
        reason = (
            f"; {text.strip().upper()} has no fixed value range, give --value-range LO,HI"
            if text.strip().upper() in UNSUPPORTED
            else ""
        )
        raise argparse.ArgumentTypeError(
            f"expected one of {', '.join(MODALITY_CHOICES)}, got {text!r}{reason}"
        ) from exc
    return text.strip().upper()


def oblique_type(text: str) -> tuple[tuple[float, float, float] | None, tuple[float, float, float]]:
    """``--oblique CX,CY,CZ:NX,NY,NZ`` (or ``:NX,NY,NZ`` for the volume's centre) -> (centre, normal).

    >>> oblique_type("1,2,3:0,0,1"), oblique_type(":1,1,0")
    (((1.0, 2.0, 3.0), (0.0, 0.0, 1.0)), (None, (1.0, 1.0, 0.0)))
    """
    expected = "CX,CY,CZ:NX,NY,NZ (a world point and a non-zero normal; ':NX,NY,NZ' for the volume's centre)"
    centre_text, sep, normal_text = text.partition(":")
    try:
        centre = tuple(float(p) for p in centre_text.split(",")) if centre_text.strip() else None
        normal = tuple(float(p) for p in normal_text.split(","))
    except ValueError:
        centre, normal = (), ()
    ok = (
        sep
        and len(normal) == 3
        and (centre is None or len(centre) == 3)
        and all(math.isfinite(v) for v in (centre or ()) + normal)
        and any(v != 0 for v in normal)
    )
    if not ok:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return centre, normal  # type: ignore[return-value]


# -- option groups ----------------------------------------------------------------------------
def add_view_option(p: argparse.ArgumentParser) -> None:
    """``hevr render --view``."""
    p.add_argument(
        "--view",
        choices=VIEWS,
        metavar="VIEW",
        help=f"anatomical view of a scan in the RAS+ patient frame: {', '.join(VIEWS)} (anterior: "
        "facing the patient, their right on the image's left); --azimuth/--elevation then "
        "turn about the view's up axis / tilt towards it",
    )


def add_encrypt_scan_options(p: argparse.ArgumentParser) -> None:
    """``hevr encrypt``'s options for real scans."""
    p.add_argument(
        "--modality",
        type=modality_type,
        default="auto",
        metavar="|".join(MODALITY_CHOICES),
        help="value range of the modality when --value-range is not given: CT (-1024, 3071) HU, "
        "MR (0, 4095), US (0, 255); auto (default): the modality the file records (DICOM), else "
        "the dtype's range (integers) or the data range (floats)",
    )
    add_scan_read_options(p)
    p.add_argument(
        "--nan-as",
        type=finite_float,
        metavar="VALUE",
        help="float scans: encrypt NaN voxels (no measurement) as VALUE; without it a scan with NaN voxels is refused",
    )


def add_finish_option(p: argparse.ArgumentParser) -> None:
    """``--finish`` of render, recolour and slice."""
    p.add_argument(
        "--finish",
        choices=("client", "server"),
        default="client",
        help="client (default): the cluster packs only the ray sums of the stored channel; the density "
        "or transfer function stays in this process, is not written to the frame and is applied "
        "at 'hevr decrypt' (the command is printed); server: the paper's way, the cluster combines, "
        "normalises and packs finished pixels (the colouring goes to the workers and into the frame)",
    )


def add_decrypt_colour_options(p: argparse.ArgumentParser) -> None:
    """``hevr decrypt --mode / --density / --tf / --value-range``: the colouring of a client frame."""
    g = p.add_argument_group("colouring a client-finished frame (hevr render --finish client, the default)")
    g.add_argument(
        "--mode",
        choices=("xray", "emphasize", "tf"),
        help="default: emphasize with --density, tf with --tf, xray for an X-ray frame",
    )
    g.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    g.add_argument(
        "--tf", type=tf_type, metavar="NODES", help=TF_HELP.replace("the store's value range", "--value-range")
    )
    g.add_argument(
        "--value-range",
        type=range_type,
        metavar="LO,HI",
        help="the store's value range (hevr info STORE), for a --tf preset: a frame does not record it",
    )


def add_server_option(p: argparse.ArgumentParser, server_help: str | None = None) -> None:
    """``--server URL`` / ``--cafile`` / ``--timeout`` / ``--connect-timeout``: render on ``hevr serve``
    (STORE is then the name or id it serves the store under; ``--key`` verifies the answer); the token
    comes from the environment (``HEVR_TOKEN``), never the command line (other users see it).
    ``server_help``: another command's words for ``--server`` (``hevr stores``)."""
    g = p.add_argument_group("render server (hevr serve)")
    g.add_argument(
        "--server",
        metavar="URL",
        help=server_help
        or "render on this hevr serve (http(s)://host:port) as "
        "its key holder: STORE is then the name (or store id) it printed; with --key KEY.json the answer "
        "is verified here; the token comes from the environment variable HEVR_TOKEN; nothing the server "
        "sends is run or unpickled",
    )
    g.add_argument("--cafile", metavar="PEM", help="CA bundle to trust for an https --server")
    g.add_argument(
        "--timeout",
        type=float,
        default=600.0,
        metavar="S",
        help="seconds for each whole exchange with the server: connecting, the answer's head and body, "
        "waits for a busy server (default 600; decryption here is not counted)",
    )
    g.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds for the connection to the server (TCP and TLS; default 10)",
    )
