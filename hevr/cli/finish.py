"""Client finishing on the command line: the lines that tell where a frame gets its colours
(``--finish`` of render, recolour and slice and the colouring options of ``hevr decrypt`` are in
:mod:`hevr.cli.render_options`).

With ``--finish client`` (the default) a frame holds the ray sums of the stored channel, not the
density or transfer function (:mod:`hevr.colour`): the command that renders it prints the exact
``hevr decrypt … --tf … | --density …`` that colours it, on the key holder's machine.
"""

from __future__ import annotations

from typing import Any

from .render_options import format_tf
from .storage import png_name

__all__ = ["colour_options", "report_finish"]


def colour_options(mode: str, density: float | None, nodes: Any) -> str:
    """The options of ``hevr decrypt`` that colour a client-finished frame as ``mode`` /
    ``density`` / ``nodes`` ask (nothing for an X-ray): exact, so the decrypted frame is the
    render's.

    >>> colour_options("tf", None, [(0.279, "blue"), (0.8, (1, 0, 0))]), colour_options("emphasize", 0.653, None)
    (" --tf '0.279:#0000ff,0.8:#ff0000'", ' --density 0.653')
    """
    if mode == "emphasize":
        if density is None:
            raise ValueError("colour_options: expected the density of an emphasis, got None")
        return f" --density {float(density)!r}"
    if mode == "tf":
        hexes = (format_tf([(0.0, c)]).partition(":")[2] for _, c in nodes)
        return " --tf '" + ",".join(f"{float(d)!r}:{h}" for (d, _), h in zip(nodes, hexes)) + "'"
    return ""


def report_finish(img: Any, out: Any, mode: str, density: float | None, nodes: Any) -> None:
    """The closing lines of render, recolour and slice: where the colouring happens and the
    exact ``hevr decrypt`` command of the frame ``out``."""
    opts = colour_options(mode, density, nodes) if img.finish == "client" else ""
    if img.finish == "client" and mode != "xray":
        what = "density" if mode == "emphasize" else "transfer function"
        print(
            f"colour:  applied at decryption: {out} holds the {img.channel} channel's ray sums "
            f"({img.values_per_pixel} per pixel), not the {what} (neither sent to the workers nor written)"
        )
    print(f"decrypt it with: hevr decrypt {out} --key KEY.json --out {png_name(out)}{opts}")
