"""Client finishing on the command line: ``--finish`` of render, recolour and slice, the
colouring options of ``hevr decrypt`` and the lines that tell where a frame gets its colours.

With ``--finish client`` (the default) a frame holds the ray sums of the stored channel, not the
density or transfer function (:mod:`hevr.colour`): the command that renders it prints the exact
``hevr decrypt … --tf … | --density …`` that colours it, on the key holder's machine.
"""

from __future__ import annotations

import argparse
from typing import Any

from ..paper import PAPER_DENSITIES, PAPER_TF1
from .options import range_type, tf_type, unit_float
from .scan import TF_HELP
from .storage import png_name
from .util import format_tf

__all__ = ["DECRYPT_DESCRIPTION", "DECRYPT_EPILOG", "add_decrypt_colour_options", "add_finish_option",
           "colour_options", "report_finish"]

DECRYPT_DESCRIPTION = (
    "Decrypt an encrypted .hevr frame with the private key and write a PNG. A frame finished on the client "
    "(hevr render's default) holds the ray sums of the stored channel, not their colouring: an X-ray decrypts as "
    "it is; an emphasis or transfer-function frame takes --density or --tf here, on this machine (any other "
    "density or transfer function too: re-colouring needs no server). A frame rendered with --finish server is "
    "coloured already and takes neither.")
DECRYPT_EPILOG = (
    "examples:\n  hevr decrypt xray.hevr --key key.json --out xray.png --npy xray.npy\n"
    f"  hevr decrypt tf.hevr --key key.json --out tf.png --tf '{format_tf(PAPER_TF1)}'\n"
    f"  hevr decrypt tf.hevr --key key.json --out emph.png --density {PAPER_DENSITIES[1]}\n"
    "  hevr decrypt bone.hevr --key key.json --tf ct-bone --value-range=-1024,3071\n")


def add_finish_option(p: argparse.ArgumentParser) -> None:
    """``--finish`` of render, recolour and slice."""
    p.add_argument("--finish", choices=("client", "server"), default="client",
                   help="client (default): the cluster packs only the ray sums of the stored channel; the density "
                        "or transfer function stays in this process, is not written to the frame and is applied "
                        "at 'hevr decrypt' (the command is printed); server: the paper's way, the cluster combines, "
                        "normalises and packs finished pixels (the colouring goes to the workers and into the frame)")


def add_decrypt_colour_options(p: argparse.ArgumentParser) -> None:
    """``hevr decrypt --mode / --density / --tf / --value-range``: the colouring of a client frame."""
    g = p.add_argument_group("colouring a client-finished frame (hevr render --finish client, the default)")
    g.add_argument("--mode", choices=("xray", "emphasize", "tf"),
                   help="default: emphasize with --density, tf with --tf, xray for an X-ray frame")
    g.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    g.add_argument("--tf", type=tf_type, metavar="NODES", help=TF_HELP.replace("the store's value range",
                                                                           "--value-range"))
    g.add_argument("--value-range", type=range_type, metavar="LO,HI",
                   help="the store's value range (hevr info STORE), for a --tf preset: a frame does not record it")


def colour_options(mode: str, density: float | None, nodes: Any) -> str:
    """The options of ``hevr decrypt`` that colour a client-finished frame as ``mode`` /
    ``density`` / ``nodes`` ask (nothing for an X-ray): exact, so the decrypted frame is the
    render's.

    >>> colour_options("tf", None, [(0.279, "blue"), (0.8, (1, 0, 0))]), colour_options("emphasize", 0.653, None)
    (" --tf '0.279:#0000ff,0.8:#ff0000'", ' --density 0.653')
    """
    if mode == "emphasize":
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
        print(f"colour:  applied at decryption: {out} holds the {img.channel} channel's ray sums "
              f"({img.values_per_pixel} per pixel), not the {what} (neither sent to the workers nor written)")
    print(f"decrypt it with: hevr decrypt {out} --key KEY.json --out {png_name(out)}{opts}")
