"""The arguments of the data-path commands: ``encrypt``, ``render``, ``recolour``, ``slice``,
``decrypt``, ``pyramid`` and ``demo`` (their descriptions and examples too).

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
    PAPER_SIZE,
    PAPER_TF1,
    PAPER_TF2,
    tf_text,
)
from .options import (
    add_general_options,
    add_storage_option,
    bits_type,
    brick_type,
    digits_type,
    finite_float,
    floats_type,
    phantom_size_type,
    positive_float,
    positive_int,
    precision_type,
    range_type,
    unit_float,
    vector_dims_type,
)
from .parser import wrap
from .render_options import (
    TF_HELP,
    add_decrypt_colour_options,
    add_encrypt_scan_options,
    add_finish_option,
    add_require_verified_option,
    add_server_option,
    add_verify_option,
    add_view_option,
    format_tf,
    level_type,
    levels_type,
    oblique_type,
    size_type,
    tf_type,
)

__all__ = [
    "DECRYPT_DESCRIPTION",
    "DECRYPT_EPILOG",
    "DEMO_EPILOG",
    "PYRAMID_EPILOG",
    "SLICE_EPILOG",
    "decrypt_arguments",
    "demo_arguments",
    "encrypt_arguments",
    "pyramid_arguments",
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

PYRAMID_EPILOG = """\
examples:
  hevr pyramid vol.zarr                  # level 1: 8x fewer voxels
  hevr pyramid vol.zarr --levels 3 --workers 2
  hevr render vol.zarr --out preview.hevr --level 2   # a quick preview, same camera options

A level's voxel is the mean of its 2x2x2 children (edge voxels repeated at odd sizes); levels
already built are kept, an interrupted level is finished. The store gains levels/L arrays and
OME-Zarr multiscales metadata; no key is needed and nothing about the data is revealed.
"""

DEMO_EPILOG = f"""\
examples:
  hevr demo                                   # 15-25 s on a 2-core laptop (32^3, 48x48 px, 512-bit key)
  hevr demo --out figs --size 64 --image 96x96
  hevr demo --size {PAPER_SIZE} --image {PAPER_IMAGE}x{PAPER_IMAGE} --bits 2048   # the paper's setting: ~25 min on 2 cores (README)
  hevr demo --input tooth_103x94x161_uint8.raw --image 128x128
  hevr demo --scheduler tcp://10.0.0.5:8786   # render on a running cluster (DIR must be shared)

Writes into DIR: demo-key.json (+ .pub.json), volume.zarr, one .hevr frame and two PNGs per
image (<name>.png decrypted, <name>.ref.png plaintext reference), contact-sheet.png,
report.md and summary.json. The timings are printed as tables. A second run into DIR
replaces what the first one wrote (recorded in DIR/.hevr-outputs.json); a file at one of
these names that the demo did not write is refused (exit 2) unless --force.
Keys below 2048 bits are NOT secure; the small default only keeps the demo fast.
"""


def encrypt_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr encrypt``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    add_storage_option(p)
    p.description = wrap(
        "Encrypt a volume voxel by voxel into a Zarr v3 store of Paillier ciphertexts, "
        "one Dask task per brick. The store holds the public key and ciphertexts only."
    )
    p.epilog = (
        "examples (the owner encrypts with the private key: the fast path; key.pub.json for anyone else):\n"
        f"  hevr encrypt phantom:{PAPER_SIZE} --key key.json --out vol.zarr --vector-dims 4\n"
        "  hevr encrypt tooth_103x94x161_uint8.raw --key key.json --out tooth.zarr --workers 2\n"
        "  hevr encrypt ct.nii.gz --key key.json --out ct.zarr --modality CT --resume\n"
        "  hevr encrypt dicom/ --key key.json --out ct.zarr --series 1.2.840.1 --vector-dims 8\n"
        "  hevr encrypt sample:mri --key key.json --out mri.zarr --vector-dims 4\n"
        "  hevr encrypt ct.nii.gz --key key.pub.json --out ct.zarr   # not the owner: public key, slower\n"
        "\nINPUT: .npy, .raw (shape/type from a name like tooth_103x94x161_uint8.raw), .nrrd, "
        ".nhdr,\n.nii/.nii.gz, .mgz/.mgh, .tif/.tiff, a DICOM file (.dcm: that file alone), a DICOM "
        "folder or\nDICOMDIR, a Zarr/OME-Zarr folder, phantom:N (the paper's test object, N^3 voxels) "
        "or\nsample:mri (a small MRI that ships with nibabel).\n"
        "Scans that record their orientation are read into the RAS+ patient frame (render --view).\n"
        "A private --key selects the owner-side fast path (exact textbook ciphertexts, faster).\n"
        "Progress: ciphertexts done, the rate and the time left (log lines when stderr is not a "
        "terminal).\n"
    )
    p.add_argument("input", metavar="INPUT", help="volume file or folder, phantom:N or sample:mri (formats below)")
    p.add_argument("--key", required=True, metavar="KEY", help="public key (key.pub.json) or private key file")
    p.add_argument("--out", required=True, metavar="STORE", help="target store, e.g. vol.zarr")
    p.add_argument(
        "--vector-dims",
        type=vector_dims_type,
        metavar="K",
        help="also store the paper's K-dimensional density encoding (needed for emphasize/tf; the paper uses 4)",
    )
    p.add_argument("--brick", type=brick_type, default=32, metavar="N|BZ,BY,BX", help="brick edge (default 32)")
    p.add_argument("--resume", action="store_true", help="finish an interrupted run (only missing bricks)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store")
    p.add_argument("--no-scalar", action="store_true", help="skip the scalar channel (no X-ray rendering)")
    p.add_argument(
        "--gradient",
        action="store_true",
        help="also store the gradient-modulated encoding g*e(d) (needs --vector-dims; k more ciphertexts "
        "per voxel) for 'hevr render --gradient'",
    )
    p.add_argument(
        "--verifiable",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also store a tag channel beside every channel, so that renders are checked against a lying "
        "server at 'hevr decrypt' (needs the private --key; twice the ciphertexts and about twice "
        "the encryption time); default: on for a packed store encrypted with the private key, off "
        "otherwise (--no-verifiable: no tags)",
    )
    p.add_argument(
        "--layout",
        choices=("voxel", "packed"),
        default="voxel",
        help="'voxel': one ciphertext per voxel (default; every render); 'packed': S voxels per "
        "ciphertext along --pack-axis (about S times smaller and faster to encrypt; X-ray frames of "
        "parallel cameras around that axis, 'hevr render STORE'; with --vector-dims and --gradient "
        "their channels packed alike, for colour frames in Python)",
    )
    p.add_argument(
        "--pack-axis",
        choices=("z", "y", "x"),
        default=None,
        help="the packing axis of --layout packed (default z: the patient's superior axis in RAS+)",
    )
    p.add_argument(
        "--levels",
        type=levels_type,
        default=0,
        metavar="L",
        help="also pyramid levels 1..L for previews ('hevr render --level'): a packed store's are "
        "encrypted here with slots of their own (the server cannot build them); a per-voxel "
        "store's are built after level 0 as 'hevr pyramid' does",
    )
    p.add_argument(
        "--value-range",
        type=range_type,
        metavar="LO,HI",
        help="density normalisation range (default: the --modality range, else the dtype's range "
        "for integers, the data range for floats)",
    )
    p.add_argument("--digits", type=digits_type, metavar="D", help="decimal digits kept of float voxels (default 3)")
    p.add_argument(
        "--spacing",
        type=floats_type(3, "SX,SY,SZ", positive=True),
        metavar="SX,SY,SZ",
        help="voxel spacing, overriding the file's",
    )
    p.add_argument(
        "--trust-scheduler",
        action="store_true",
        help="allow a private --key with --scheduler (sends p, q to that cluster's workers)",
    )
    add_encrypt_scan_options(p)


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


def pyramid_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr pyramid``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    add_storage_option(p)
    p.description = wrap(
        "Compute the encrypted multi-resolution pyramid of a store on the cluster: level "
        "L+1 holds the means of 2x2x2 voxels of level L, computed on the ciphertexts. "
        "'hevr render --level L' renders a level with the same camera, about 8^L times "
        "less work."
    )
    p.epilog = PYRAMID_EPILOG
    p.add_argument("store", metavar="STORE", help="encrypted volume store")
    p.add_argument(
        "--levels", type=levels_type, default=1, metavar="N", help="build levels 1..N (default 1, at most 8)"
    )


def demo_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr demo``: its description, examples and arguments."""
    add_general_options(p, dask=True, workers_default="2 (a 2-worker local cluster)")
    p.description = wrap(
        "Generate the paper's phantom (or read --input), make a key, encrypt, render the "
        "paper's figure set on a local Dask cluster, decrypt, and compare every image with "
        "its plaintext reference. Writes PNGs, a contact sheet, report.md and summary.json."
    )
    p.epilog = DEMO_EPILOG
    p.add_argument("--out", default="hevr-demo", metavar="DIR", help="output folder (default hevr-demo)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace files in DIR at the demo's names that an earlier demo run did not write",
    )
    p.add_argument(
        "--size", type=phantom_size_type, default=32, metavar="N", help="phantom edge in voxels (default 32)"
    )
    p.add_argument("--image", type=size_type, default=(48, 48), metavar="WxH", help="image size (default 48x48)")
    p.add_argument("--bits", type=bits_type, default=512, metavar="B", help="key size (default 512: demo only)")
    p.add_argument(
        "--input", metavar="FILE", help="render this volume (any INPUT of 'hevr encrypt') instead of the phantom"
    )
    p.add_argument("--brick", type=brick_type, metavar="N|BZ,BY,BX", help="brick edge (default: a third of the volume)")
    p.add_argument("--azimuth", type=finite_float, default=30.0, metavar="DEG", help="camera azimuth (default 30)")
    p.add_argument("--elevation", type=finite_float, default=20.0, metavar="DEG", help="camera elevation (default 20)")
    p.add_argument(
        "--packed",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also encrypt the volume as a packed store (verifiable) and render a verified parallel X-ray "
        "of it beside the per-voxel store's (default; --no-packed leaves it out)",
    )
