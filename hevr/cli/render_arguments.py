"""The arguments of the key holder's data-path commands: ``render``, ``recolour``, ``slice`` and
``decrypt`` (their descriptions and examples too); those of the owner's (``encrypt``, ``pyramid``,
``demo``) are in :mod:`hevr.cli.owner_arguments`.

:mod:`hevr.cli.parser` calls one of these functions on the command's empty subparser, only for
the command being run. Their help and checks quote the render side's tables (transfer-function
presets, views, modalities, pyramid levels, the render pixel limit: :mod:`hevr.cli.render_options`),
which is why they are not in :mod:`hevr.cli.arguments` with the commands that start without them.
"""

from __future__ import annotations

import argparse

from ..paper import (
    PAPER_DENSITIES,
    PAPER_IMAGE,
    PAPER_TF1,
    PAPER_TF2,
    tf_text,
)
from .options import (
    add_general_options,
    add_storage_option,
    finite_float,
    positive_float,
    positive_int,
    precision_type,
    range_type,
    unit_float,
)
from .parser import wrap
from .render_options import (
    TF_HELP,
    add_decrypt_colour_options,
    add_finish_option,
    add_server_option,
    add_view_option,
    format_tf,
    level_type,
    oblique_type,
    size_type,
    tf_type,
)
from .verify_options import add_require_verified_option, add_verify_option

__all__ = [
    "DECRYPT_DESCRIPTION",
    "DECRYPT_EPILOG",
    "SLICE_EPILOG",
    "decrypt_arguments",
    "recolour_arguments",
    "render_arguments",
    "slice_arguments",
]

DECRYPT_DESCRIPTION = (
    "Decrypt an encrypted .hevr frame with the private key and write a PNG. A frame finished on the client "
    "(hevr render's default) holds the ray sums of the stored channel, not their colouring: an X-ray decrypts as "
    "it is; an emphasis or transfer-function frame takes --density or --tf here, on this machine (any other "
    "density or transfer function too: re-colouring needs no server). A frame rendered with --finish server is "
    "coloured already and takes neither."
)
DECRYPT_EPILOG = (
    "examples:\n  hevr decrypt xray.hevr --key key.json --out xray.png --npy xray.npy\n"
    f"  hevr decrypt tf.hevr --key key.json --out tf.png --tf '{format_tf(PAPER_TF1)}'\n"
    f"  hevr decrypt tf.hevr --key key.json --out emph.png --density {PAPER_DENSITIES[1]}\n"
    "  hevr decrypt bone.hevr --key key.json --tf ct-bone --value-range=-1024,3071\n"
)

SLICE_EPILOG = """\
examples:
  hevr slice vol.zarr --out axial.hevr --axial 50                 # layer 50 as it is stored (x across, y down)
  hevr slice vol.zarr --out cor.hevr --coronal 40 --size 150x150 --sampling trilinear
  hevr slice vol.zarr --out obl.hevr --oblique 50,50,50:1,1,0 --pixel-spacing 0.5 --size 200x200
  hevr slice vol.zarr --out slab.hevr --axial 50 --slab 5 --slab-step 1   # mean of 5 planes (no MIP: see README)
  hevr slice vol.zarr --out tf.hevr --sagittal 30 --tf '0.279:blue,0.797:red'

Rows and columns follow the array: --axial K is vol[K] (x across, y down), --coronal J is
vol[:, J, :] (x across, z down), --sagittal I is vol[:, :, I] (y across, z down). Without
--size or --pixel-spacing the image is the volume's own grid; --size alone fits the volume
into it with square pixels; --oblique CX,CY,CZ:NX,NY,NZ centres the image on the world point C
(':NX,NY,NZ': the volume's centre) with normal N. Pixels outside the volume are 0.
--mode defaults to emphasize with --density, tf with --tf, else xray; with --finish client (the
default) the density or transfer function is applied at 'hevr decrypt' (the command is printed).
"""


def render_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr render``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    add_storage_option(p)
    p.description = wrap(
        "Ray-cast an encrypted volume on the Dask cluster. Never needs the secret key: "
        "the result is an encrypted .hevr frame only the key holder can decrypt. By "
        "default (--finish client) the cluster computes only the ray sums of the stored "
        "channel: the density or transfer function is applied at decryption ('hevr "
        "decrypt --density / --tf'; the command is printed) and is neither sent to the "
        "workers nor written to the frame."
    )
    p.epilog = (
        "examples:\n"
        "  hevr render vol.zarr --out xray.hevr --sampling trilinear --azimuth 30 --elevation 20\n"
        f"  hevr render vol.zarr --out emph.hevr --mode emphasize --density {PAPER_DENSITIES[1]}\n"
        f"  hevr render vol.zarr --out tf.hevr --mode tf --tf '{format_tf(PAPER_TF2)}'\n"
        "  hevr render ct.zarr --out bone.hevr --view anterior --azimuth 30 --tf ct-bone\n"
        "  hevr render ct-packed.zarr --out xray.hevr --key key.json --sampling trilinear"
        "   # a packed store: a verified parallel X-ray\n"
        f"  hevr render vol.zarr --out tf.hevr --tf '{format_tf(PAPER_TF2)}' --finish server"
        "   # the paper's way\n"
        "\n--mode defaults to emphasize with --density, tf with --tf, else xray.\n"
        "A packed store (hevr encrypt --layout packed) renders parallel X-ray frames of views around its\n"
        "packing axis (default: --view anterior, or left for a store packed along y); options it cannot\n"
        "serve (--mode emphasize/tf, --step, --finish server, --view-angle, --keep-sums, --no-pack,\n"
        "--gradient) are refused.\n"
    )
    p.add_argument("store", metavar="STORE", help="encrypted volume store (hevr encrypt)")
    p.add_argument("--out", required=True, metavar="FRAME.hevr", help="encrypted image file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out (and --keep-sums) file")
    p.add_argument("--mode", choices=("xray", "emphasize", "tf"), help="render mode (default: see below)")
    p.add_argument(
        "--sampling",
        choices=("nearest", "trilinear"),
        default="nearest",
        help="sampling along the rays (default nearest)",
    )
    p.add_argument(
        "--azimuth",
        type=finite_float,
        default=None,
        metavar="DEG",
        help="camera azimuth about the y axis (default 0: looking from +z); with --view, about the view's up axis",
    )
    p.add_argument("--elevation", type=finite_float, default=None, metavar="DEG", help="camera elevation (default 0)")
    add_view_option(p)
    p.add_argument(
        "--size",
        type=size_type,
        default=(PAPER_IMAGE, PAPER_IMAGE),
        metavar="WxH",
        help=f"image size (default {PAPER_IMAGE}x{PAPER_IMAGE})",
    )
    p.add_argument(
        "--view-angle",
        type=positive_float,
        default=None,
        metavar="DEG",
        help="vertical view angle (default 30; perspective cameras only)",
    )
    p.add_argument(
        "--parallel", action="store_true", help="parallel projection instead of perspective (always, on a packed store)"
    )
    p.add_argument(
        "--step",
        type=positive_float,
        default=None,
        metavar="S",
        help="sample spacing in world units (default 1; a packed store samples once per slice)",
    )
    p.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    p.add_argument("--tf", type=tf_type, metavar="NODES", help=f"{TF_HELP}; default {tf_text(PAPER_TF1)}")
    p.add_argument("--no-pack", action="store_true", help="one pixel value per ciphertext (bigger, slower to decrypt)")
    p.add_argument(
        "--gradient",
        action="store_true",
        help="weight every sample by the gradient magnitude (emphasize/tf; a store encrypted with --gradient)",
    )
    p.add_argument(
        "--precision",
        type=precision_type,
        default=4,
        metavar="P",
        help="decimal digits of the normalisation (--finish server; default 4)",
    )
    add_finish_option(p)
    add_verify_option(p)
    add_server_option(p)
    p.add_argument(
        "--level",
        type=level_type,
        default=0,
        metavar="L",
        help="render pyramid level L (hevr pyramid; default 0: the full volume)",
    )
    p.add_argument(
        "--keep-sums",
        metavar="SUMS",
        help="also write the view's encrypted ray sums (ciphertexts only: "
        "safe on the server) so that 'hevr recolour SUMS' can finish another --density or --tf "
        "without the map step",
    )


def recolour_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr recolour``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    add_storage_option(p)
    p.description = wrap(
        "Finish the encrypted ray sums written by 'hevr render --keep-sums' with another "
        "emphasis density or transfer function: only the per-pixel step runs, and the "
        "frame is bit for bit what 'hevr render' with the same options writes. Never "
        "needs the secret key. With --finish client (the default) the frame holds the "
        "sums and the colouring is applied at decryption: 'hevr decrypt --tf / --density' "
        "re-colours a client frame without any server work."
    )
    p.epilog = (
        "examples:\n"
        f"  hevr render vol.zarr --out tf1.hevr --tf '{format_tf(PAPER_TF1)}' --keep-sums view.hevrsums\n"
        f"  hevr recolour view.hevrsums --out tf2.hevr --tf '{format_tf(PAPER_TF2)}'\n"
        f"  hevr recolour view.hevrsums --out emph.hevr --density {PAPER_DENSITIES[1]}\n"
        "\nThe camera, sampling and step are the sums'. --mode defaults to emphasize with "
        "--density, else tf;\nX-ray sums (rendered with --mode xray) re-finish only as "
        "--mode xray.\n"
    )
    p.add_argument("sums", metavar="SUMS", help="ray-sums file (hevr render --keep-sums)")
    p.add_argument("--out", required=True, metavar="FRAME.hevr", help="encrypted image file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.add_argument("--mode", choices=("xray", "emphasize", "tf"), help="render mode (default: see below)")
    p.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    p.add_argument("--tf", type=tf_type, metavar="NODES", help=TF_HELP)
    p.add_argument("--no-pack", action="store_true", help="one pixel value per ciphertext")
    p.add_argument(
        "--gradient",
        action="store_true",
        help="weight every sample by the gradient magnitude (emphasize/tf; a store encrypted with --gradient)",
    )
    p.add_argument(
        "--precision",
        type=precision_type,
        default=4,
        metavar="P",
        help="decimal digits of the normalisation (--finish server; default 4)",
    )
    add_finish_option(p)


def slice_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr slice``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    add_storage_option(p)
    p.description = wrap(
        "Resample the encrypted volume on a plane (multi-planar reformatting), optionally "
        "averaging a thick slab of parallel planes, on the Dask cluster. Never needs the "
        "secret key: the result is an encrypted .hevr frame only the key holder can decrypt. "
        "hevr decrypt writes its PNG in the radiological convention (axial: anterior at the top, "
        "the patient's right on the left; coronal, sagittal: superior at the top)."
    )
    p.epilog = SLICE_EPILOG
    p.add_argument("store", metavar="STORE", help="encrypted volume store (hevr encrypt)")
    p.add_argument("--out", required=True, metavar="FRAME.hevr", help="encrypted image file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--axial", type=finite_float, metavar="K", help="the plane z = K·sz (layer K of the array)")
    g.add_argument("--coronal", type=finite_float, metavar="J", help="the plane y = J·sy")
    g.add_argument("--sagittal", type=finite_float, metavar="I", help="the plane x = I·sx")
    g.add_argument(
        "--oblique",
        type=oblique_type,
        metavar="CX,CY,CZ:NX,NY,NZ",
        help="the plane through world point C with normal N (':NX,NY,NZ': through the volume's centre)",
    )
    p.add_argument("--size", type=size_type, metavar="WxH", help="image size (default: see below)")
    p.add_argument(
        "--pixel-spacing", type=positive_float, metavar="D", help="world units per pixel (default: see below)"
    )
    p.add_argument(
        "--slab", type=positive_int, default=1, metavar="N", help="average N parallel planes (a thick slab; default 1)"
    )
    p.add_argument(
        "--slab-step",
        type=positive_float,
        metavar="S",
        help="world distance between the slab's planes (default: the voxel spacing along the normal)",
    )
    p.add_argument(
        "--sampling",
        choices=("nearest", "trilinear"),
        default="nearest",
        help="sampling of the volume (default nearest)",
    )
    p.add_argument("--mode", choices=("xray", "emphasize", "tf"), help="xray: the value; emphasize, tf as in render")
    p.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    p.add_argument("--tf", type=tf_type, metavar="NODES", help=TF_HELP)
    p.add_argument("--no-pack", action="store_true", help="one pixel value per ciphertext")
    p.add_argument(
        "--gradient",
        action="store_true",
        help="weight every sample by the gradient magnitude (emphasize/tf; a store encrypted with --gradient)",
    )
    p.add_argument(
        "--precision",
        type=precision_type,
        metavar="P",
        help="decimal digits of the normalisation (--finish server; default 0 where it is exact: "
        "one plane in mode xray or emphasize; else 4)",
    )
    add_finish_option(p)
    add_verify_option(p)
    add_server_option(p)


def decrypt_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr decrypt``: its description, examples and arguments."""
    add_general_options(p, dask=False)
    add_storage_option(p)
    p.description = wrap(DECRYPT_DESCRIPTION)
    p.epilog = DECRYPT_EPILOG
    p.add_argument("frame", metavar="FRAME", help="encrypted image (.hevr)")
    p.add_argument("--key", required=True, metavar="KEY.json", help="private key file")
    p.add_argument("--out", metavar="PNG", help="PNG to write (default: FRAME with .png)")
    p.add_argument("--npy", metavar="FILE.npy", help="also save the float64 pixel values")
    p.add_argument("--force", action="store_true", help="replace an existing --out (or --npy) file")
    p.add_argument(
        "--window",
        type=range_type,
        metavar="LO,HI",
        help="grey/colour window of the PNG (default 0 .. 99.9th percentile; for an image with "
        "negative values, e.g. a CT X-ray, its value range: 0.1th .. 99.9th percentile)",
    )
    add_require_verified_option(p)
    add_decrypt_colour_options(p)
