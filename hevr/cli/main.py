"""The ``hevr`` command line: keygen, encrypt, render, recolour, slice, decrypt, info, upgrade-store, demo, bench.

Run ``hevr COMMAND --help`` for each command's options and an example. An error is one line
on stderr, ``hevr: error: --key: expected a private key file, got a public key (key.pub.json)``,
that starts with the option or argument it is about, in the CLI's words (``--key``, ``INPUT``,
``STORE``), never a Python parameter's name; ``--verbose`` adds INFO logging and tracebacks.

Exit status, one rule for every command, applied in :func:`main` only (by error class:
:mod:`hevr.cli.exits`, which also holds each command's Python-name -> option mapping):

* 0 - done (``hevr info``: and every check passed).
* 2 - the command line asks for something that cannot be done as given: argparse's errors,
  bad option values or combinations, a named file that is missing or of the wrong kind (not a
  key, store, frame or volume hevr reads; a public key where the private one is needed), an
  output that exists without ``--force``/``--overwrite``, a key of another volume, a render the
  planner refuses (the message names the option to change). Fix the command line.
* 1 - the data or the run failed: a corrupt, tampered or incomplete store or frame, a failed
  integrity check (``hevr info`` whose check fails too), an I/O failure, a missing optional
  dependency, a memory limit, a crashed worker or any other error.
* 130 - interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import logging
import sys
import textwrap
import traceback
import warnings
from typing import Any, Sequence

from .. import __version__
from ..paper import (
    PAPER_DENSITIES,
    PAPER_IMAGE,
    PAPER_SIZE,
    PAPER_TF1,
    PAPER_TF2,
    tf_text,
)
from . import commands as cmds
from . import demo as demo
from .bench import BENCH_EPILOG, cmd_bench
from .demo import DEMO_EPILOG
from .exits import EXIT_RULE, cli_message, exit_code
from .finish import DECRYPT_DESCRIPTION, DECRYPT_EPILOG, add_decrypt_colour_options, add_finish_option
from .options import (
    bits_type,
    brick_type,
    digits_type,
    finite_float,
    floats_type,
    join_negative_values,
    level_type,
    levels_type,
    phantom_size_type,
    positive_float,
    positive_int,
    precision_type,
    range_type,
    size_type,
    tf_type,
    unit_float,
    value_options,
    vector_dims_type,
    workers_type,
)
from .pyramid import PYRAMID_EPILOG, cmd_pyramid
from .scan import TF_HELP, add_encrypt_scan_options, add_scan_read_options, add_view_option
from .slice import SLICE_EPILOG, cmd_slice, oblique_type
from .storage import storage_parent
from .util import err_line, format_tf, show_warning, silence_stdout

__all__ = ["main", "build_parser"]

_RAW = argparse.RawDescriptionHelpFormatter


def _d(text: str) -> str:
    """Wrap a description (RawDescriptionHelpFormatter keeps the examples' layout)."""
    return textwrap.fill(text, 88)


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is ONE line on stderr (exit code 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        err_line(f"{message} (see '{self.prog} --help')")
        raise SystemExit(2)


def _common(dask: bool, workers_default: str = "Dask's default threaded scheduler") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("general options")
    if dask:
        g.add_argument("--scheduler", metavar="ADDRESS",
                       help="join a running Dask cluster, e.g. tcp://10.0.0.5:8786 (store paths must be "
                            "reachable from its workers)")
        g.add_argument("--workers", type=workers_type, metavar="N",
                       help="start a local Dask cluster of N worker processes (1 thread each) for this "
                            f"command (0: none); default: {workers_default}")
    g.add_argument("-v", "--verbose", action="store_true", help="INFO logging, and tracebacks on errors")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bars (they are only drawn on a terminal anyway)")
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hevr", formatter_class=_RAW,
        description=_d("Privacy-preserving remote volume rendering on Paillier-encrypted volumes "
                    "(after Mazza, Patel, Viola, TVCG 2020)."),
        epilog="typical session:\n"
               "  hevr keygen --bits 2048 --out key.json             # data owner: key pair\n"
               "  hevr encrypt phantom:64 --key key.json --out vol.zarr --vector-dims 4\n"
               "  hevr render vol.zarr --out frame.hevr --mode tf        # server side: the ray sums, no colours\n"
               f"  hevr decrypt frame.hevr --key key.json --out frame.png --tf '{tf_text(PAPER_TF1)}'\n"
               "                                                     # client: colours it; only the key holder sees it\n"
               "  hevr demo                                          # all of the above on the paper's figures\n"
               "\nsizes are printed in world order, labelled: x×y×z for volumes, W×H for images.\n"
               "\n" + EXIT_RULE)
    parser.add_argument("--version", action="version", version=f"hevr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    dask_opts, plain_opts = _common(True), _common(False)
    storage_opts = storage_parent()  # --storage-option: stores, frames and sums on object storage
    demo_opts = _common(True, "2 (a 2-worker local cluster)")

    p = sub.add_parser("keygen", parents=[plain_opts], formatter_class=_RAW,
                       help="generate a Paillier key pair",
                       description=_d("Generate a Paillier key pair: the private key file (mode 0600) and the "
                                   "public key beside it (key.json -> key.pub.json)."),
                       epilog="example:\n  hevr keygen --bits 2048 --out key.json\n")
    p.add_argument("--bits", type=bits_type, default=2048, help="modulus size n in bits (default 2048; "
                                                                "smaller keys are for tests and demos only)")
    p.add_argument("--out", default="key.json", metavar="KEY.json", help="private key file (default key.json)")
    p.add_argument("--force", action="store_true", help="overwrite existing key files")
    p.add_argument("--format", choices=("hevr", "phe"), default="hevr",
                   help="file format: hevr's (default) or python-paillier's pheutil JSON (phe)")

    p = sub.add_parser("convert-key", parents=[plain_opts], formatter_class=_RAW,
                       help="convert a key file between hevr's and python-paillier's (pheutil) formats",
                       description=_d("Write the key in KEY (either format; a private key stays private, mode 0600) "
                                   "in the other format. Every --key option reads both formats already."),
                       epilog="examples:\n  hevr convert-key key.json --out phe-private.json            # hevr -> pheutil\n"
                              "  hevr convert-key phe-private.json --out key.json --format hevr   # pheutil -> hevr\n"
                              "  pheutil genpkey phe.json && hevr encrypt phantom:32 --key phe.json --out v.zarr\n")
    p.add_argument("key", metavar="KEY", help="key file to read (hevr or pheutil, public or private)")
    p.add_argument("--out", required=True, metavar="FILE", help="key file to write")
    p.add_argument("--format", choices=("hevr", "phe"), default="phe", help="format to write (default phe)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out")

    p = sub.add_parser("encrypt", parents=[dask_opts, storage_opts], formatter_class=_RAW,
                       help="encrypt a volume into a Zarr store",
                       description=_d("Encrypt a volume voxel by voxel into a Zarr v3 store of Paillier ciphertexts, "
                                   "one Dask task per brick. The store holds the public key and ciphertexts only."),
                       epilog="examples:\n"
                              f"  hevr encrypt phantom:{PAPER_SIZE} --key key.pub.json --out vol.zarr --vector-dims 4\n"
                              "  hevr encrypt tooth_103x94x161_uint8.raw --key key.json --out tooth.zarr --workers 2\n"
                              "  hevr encrypt ct.nii.gz --key key.pub.json --out ct.zarr --modality CT --resume\n"
                              "  hevr encrypt dicom/ --key key.pub.json --out ct.zarr --series 1.2.840.1 --vector-dims 8\n"
                              "\nINPUT: .npy, .raw (shape/type from a name like tooth_103x94x161_uint8.raw), .nrrd, "
                              ".nhdr,\n.nii/.nii.gz, a DICOM folder, or phantom:N (the paper's test object, N^3 voxels).\n"
                              "Scans that record their orientation are read into the RAS+ patient frame (render --view).\n"
                              "A private --key selects the owner-side fast path (same ciphertexts, much faster).\n")
    p.add_argument("input", metavar="INPUT", help="volume file or folder, or phantom:N")
    p.add_argument("--key", required=True, metavar="KEY", help="public key (key.pub.json) or private key file")
    p.add_argument("--out", required=True, metavar="STORE", help="target store, e.g. vol.zarr")
    p.add_argument("--vector-dims", type=vector_dims_type, metavar="K",
                   help="also store the paper's K-dimensional density encoding (needed for emphasize/tf; "
                        "the paper uses 4)")
    p.add_argument("--brick", type=brick_type, default=32, metavar="N|BZ,BY,BX", help="brick edge (default 32)")
    p.add_argument("--resume", action="store_true", help="finish an interrupted run (only missing bricks)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store")
    p.add_argument("--no-scalar", action="store_true", help="skip the scalar channel (no X-ray rendering)")
    p.add_argument("--gradient", action="store_true",
                   help="also store the gradient-modulated encoding g*e(d) (needs --vector-dims; k more ciphertexts "
                        "per voxel) for 'hevr render --gradient'")
    p.add_argument("--value-range", type=range_type, metavar="LO,HI",
                   help="density normalisation range (default: the --modality range, else the dtype's range "
                        "for integers, the data range for floats)")
    p.add_argument("--digits", type=digits_type, metavar="D", help="decimal digits kept of float voxels (default 3)")
    p.add_argument("--spacing", type=floats_type(3, "SX,SY,SZ", positive=True), metavar="SX,SY,SZ",
                   help="voxel spacing, overriding the file's")
    p.add_argument("--trust-scheduler", action="store_true",
                   help="allow a private --key with --scheduler (sends p, q to that cluster's workers)")
    add_encrypt_scan_options(p)

    p = sub.add_parser("render", parents=[dask_opts, storage_opts], formatter_class=_RAW,
                       help="render an encrypted volume to an encrypted image (no key needed)",
                       description=_d("Ray-cast an encrypted volume on the Dask cluster. Never needs the secret key: "
                                   "the result is an encrypted .hevr frame only the key holder can decrypt. By "
                                   "default (--finish client) the cluster computes only the ray sums of the stored "
                                   "channel: the density or transfer function is applied at decryption ('hevr "
                                   "decrypt --density / --tf'; the command is printed) and is neither sent to the "
                                   "workers nor written to the frame."),
                       epilog="examples:\n"
                              "  hevr render vol.zarr --out xray.hevr --sampling trilinear --azimuth 30 --elevation 20\n"
                              f"  hevr render vol.zarr --out emph.hevr --mode emphasize --density {PAPER_DENSITIES[1]}\n"
                              f"  hevr render vol.zarr --out tf.hevr --mode tf --tf '{format_tf(PAPER_TF2)}'\n"
                              "  hevr render ct.zarr --out bone.hevr --view anterior --azimuth 30 --tf ct-bone\n"
                              f"  hevr render vol.zarr --out tf.hevr --tf '{format_tf(PAPER_TF2)}' --finish server"
                              "   # the paper's way\n"
                              "\n--mode defaults to emphasize with --density, tf with --tf, else xray.\n")
    p.add_argument("store", metavar="STORE", help="encrypted volume store (hevr encrypt)")
    p.add_argument("--out", required=True, metavar="FRAME.hevr", help="encrypted image file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out (and --keep-sums) file")
    p.add_argument("--mode", choices=("xray", "emphasize", "tf"), help="render mode (default: see below)")
    p.add_argument("--sampling", choices=("nearest", "trilinear"), default="nearest",
                   help="sampling along the rays (default nearest)")
    p.add_argument("--azimuth", type=finite_float, default=0.0, metavar="DEG",
                   help="camera azimuth about the y axis (default 0: looking from +z); with --view, about the "
                        "view's up axis")
    p.add_argument("--elevation", type=finite_float, default=0.0, metavar="DEG", help="camera elevation (default 0)")
    add_view_option(p)
    p.add_argument("--size", type=size_type, default=(PAPER_IMAGE, PAPER_IMAGE), metavar="WxH",
                   help=f"image size (default {PAPER_IMAGE}x{PAPER_IMAGE})")
    p.add_argument("--view-angle", type=positive_float, default=30.0, metavar="DEG",
                   help="vertical view angle (default 30)")
    p.add_argument("--parallel", action="store_true", help="parallel projection instead of perspective")
    p.add_argument("--step", type=positive_float, default=1.0, metavar="S", help="sample spacing in world units (default 1)")
    p.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    p.add_argument("--tf", type=tf_type, metavar="NODES",
                   help=f"{TF_HELP}; default {tf_text(PAPER_TF1)}")
    p.add_argument("--no-pack", action="store_true", help="one pixel value per ciphertext (bigger, slower to decrypt)")
    p.add_argument("--gradient", action="store_true",
                   help="weight every sample by the gradient magnitude (emphasize/tf; a store encrypted with --gradient)")
    p.add_argument("--precision", type=precision_type, default=4, metavar="P",
                   help="decimal digits of the normalisation (--finish server; default 4)")
    add_finish_option(p)
    p.add_argument("--level", type=level_type, default=0, metavar="L",
                   help="render pyramid level L (hevr pyramid; default 0: the full volume)")
    p.add_argument("--keep-sums", metavar="SUMS", help="also write the view's encrypted ray sums (ciphertexts only: "
                   "safe on the server) so that 'hevr recolour SUMS' can finish another --density or --tf "
                   "without the map step")

    p = sub.add_parser("recolour", parents=[dask_opts, storage_opts], formatter_class=_RAW,
                       help="re-colour saved ray sums with another density or transfer function (no map step)",
                       description=_d("Finish the encrypted ray sums written by 'hevr render --keep-sums' with another "
                                   "emphasis density or transfer function: only the per-pixel step runs, and the "
                                   "frame is bit for bit what 'hevr render' with the same options writes. Never "
                                   "needs the secret key. With --finish client (the default) the frame holds the "
                                   "sums and the colouring is applied at decryption: 'hevr decrypt --tf / --density' "
                                   "re-colours a client frame without any server work."),
                       epilog="examples:\n"
                              f"  hevr render vol.zarr --out tf1.hevr --tf '{format_tf(PAPER_TF1)}' --keep-sums view.hevrsums\n"
                              f"  hevr recolour view.hevrsums --out tf2.hevr --tf '{format_tf(PAPER_TF2)}'\n"
                              f"  hevr recolour view.hevrsums --out emph.hevr --density {PAPER_DENSITIES[1]}\n"
                              "\nThe camera, sampling and step are the sums'. --mode defaults to emphasize with "
                              "--density, else tf;\nX-ray sums (rendered with --mode xray) re-finish only as "
                              "--mode xray.\n")
    p.add_argument("sums", metavar="SUMS", help="ray-sums file (hevr render --keep-sums)")
    p.add_argument("--out", required=True, metavar="FRAME.hevr", help="encrypted image file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.add_argument("--mode", choices=("xray", "emphasize", "tf"), help="render mode (default: see below)")
    p.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    p.add_argument("--tf", type=tf_type, metavar="NODES", help=TF_HELP)
    p.add_argument("--no-pack", action="store_true", help="one pixel value per ciphertext")
    p.add_argument("--gradient", action="store_true",
                   help="weight every sample by the gradient magnitude (emphasize/tf; a store encrypted with --gradient)")
    p.add_argument("--precision", type=precision_type, default=4, metavar="P",
                   help="decimal digits of the normalisation (--finish server; default 4)")
    add_finish_option(p)

    p = sub.add_parser("slice", parents=[dask_opts, storage_opts], formatter_class=_RAW,
                       help="an encrypted slice (axial, coronal, sagittal, oblique) of an encrypted volume (no key needed)",
                       description=_d("Resample the encrypted volume on a plane (multi-planar reformatting), optionally "
                                   "averaging a thick slab of parallel planes, on the Dask cluster. Never needs the "
                                   "secret key: the result is an encrypted .hevr frame only the key holder can decrypt."),
                       epilog=SLICE_EPILOG)
    p.add_argument("store", metavar="STORE", help="encrypted volume store (hevr encrypt)")
    p.add_argument("--out", required=True, metavar="FRAME.hevr", help="encrypted image file to write")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--axial", type=finite_float, metavar="K", help="the plane z = K·sz (layer K of the array)")
    g.add_argument("--coronal", type=finite_float, metavar="J", help="the plane y = J·sy")
    g.add_argument("--sagittal", type=finite_float, metavar="I", help="the plane x = I·sx")
    g.add_argument("--oblique", type=oblique_type, metavar="CX,CY,CZ:NX,NY,NZ",
                   help="the plane through world point C with normal N (':NX,NY,NZ': through the volume's centre)")
    p.add_argument("--size", type=size_type, metavar="WxH", help="image size (default: see below)")
    p.add_argument("--pixel-spacing", type=positive_float, metavar="D", help="world units per pixel (default: see below)")
    p.add_argument("--slab", type=positive_int, default=1, metavar="N",
                   help="average N parallel planes (a thick slab; default 1)")
    p.add_argument("--slab-step", type=positive_float, metavar="S",
                   help="world distance between the slab's planes (default: the voxel spacing along the normal)")
    p.add_argument("--sampling", choices=("nearest", "trilinear"), default="nearest",
                   help="sampling of the volume (default nearest)")
    p.add_argument("--mode", choices=("xray", "emphasize", "tf"), help="xray: the value; emphasize, tf as in render")
    p.add_argument("--density", type=unit_float, metavar="D", help="emphasised normalised density in [0, 1]")
    p.add_argument("--tf", type=tf_type, metavar="NODES", help=TF_HELP)
    p.add_argument("--no-pack", action="store_true", help="one pixel value per ciphertext")
    p.add_argument("--gradient", action="store_true",
                   help="weight every sample by the gradient magnitude (emphasize/tf; a store encrypted with --gradient)")
    p.add_argument("--precision", type=precision_type, metavar="P",
                   help="decimal digits of the normalisation (--finish server; default 0 where it is exact: "
                        "one plane in mode xray or emphasize; else 4)")
    add_finish_option(p)

    p = sub.add_parser("decrypt", parents=[plain_opts, storage_opts], formatter_class=_RAW,
                       help="decrypt an encrypted image to PNG (and colour a client-finished frame)",
                       description=_d(DECRYPT_DESCRIPTION), epilog=DECRYPT_EPILOG)
    p.add_argument("frame", metavar="FRAME", help="encrypted image (.hevr)")
    p.add_argument("--key", required=True, metavar="KEY.json", help="private key file")
    p.add_argument("--out", metavar="PNG", help="PNG to write (default: FRAME with .png)")
    p.add_argument("--npy", metavar="FILE.npy", help="also save the float64 pixel values")
    p.add_argument("--force", action="store_true", help="replace an existing --out (or --npy) file")
    p.add_argument("--window", type=range_type, metavar="LO,HI",
                   help="grey/colour window of the PNG (default 0 .. 99.9th percentile)")
    add_decrypt_colour_options(p)

    p = sub.add_parser("info", parents=[dask_opts, storage_opts], formatter_class=_RAW,
                       help="describe a store, a frame, a key or a volume file; list a DICOM folder's series",
                       description=_d("Print what is public about a store, an encrypted frame, a key file or a "
                                   "volume file (its patient frame, modality and default value range), or the "
                                   "series a DICOM folder holds. Never prints secret-key material. A store gets "
                                   "a quick check (metadata, documents, completeness, chunk sizes: no ciphertext "
                                   "is read); --verify reads every brick back. Temporaries that an interrupted "
                                   "write left beside a store are named in a warning. Exit 1 if a check fails."),
                       epilog="examples:\n  hevr info vol.zarr\n  hevr info vol.zarr --verify   # read every brick back\n"
                              "  hevr info frame.hevr\n  hevr info key.pub.json\n"
                              "  hevr info dicom/          # its series, for hevr encrypt --series UID\n")
    p.add_argument("path", metavar="PATH")
    add_scan_read_options(p)  # a volume file: read as hevr encrypt reads it
    p.add_argument("--verify", action="store_true",
                   help="stores: also read every brick of every channel (and pyramid level) and check its "
                        "digest and every ciphertext (0 < c < n², coprime to n); names each damaged brick by "
                        "channel and index and exits 1 if any. Reads the whole store: one Dask task per brick "
                        "with --scheduler/--workers. Frames and sums files are always checked in full")

    p = sub.add_parser("upgrade-store", parents=[dask_opts], formatter_class=_RAW,
                       help="convert a format-1 store (no integrity digests) into a new format-2 store",
                       description=_d("Copy every brick of a format-1 store, unchanged and range-checked, into a new "
                                   "store with crc32c chunks and per-brick digests (docs/format.md). The old store is "
                                   "only read; no key is needed."),
                       epilog="example:\n  hevr upgrade-store old.zarr new.zarr\n")
    p.add_argument("src", metavar="OLD", help="the format-1 store")
    p.add_argument("dst", metavar="NEW", help="where the format-2 store goes (must not exist)")


    p = sub.add_parser("pyramid", parents=[dask_opts, storage_opts], formatter_class=_RAW,
                       help="add coarse levels (2x2x2 means) to a store, for quick previews (no key needed)",
                       description=_d("Compute the encrypted multi-resolution pyramid of a store on the cluster: level "
                                   "L+1 holds the means of 2x2x2 voxels of level L, computed on the ciphertexts. "
                                   "'hevr render --level L' renders a level with the same camera, about 8^L times "
                                   "less work."),
                       epilog=PYRAMID_EPILOG)
    p.add_argument("store", metavar="STORE", help="encrypted volume store")
    p.add_argument("--levels", type=levels_type, default=1, metavar="N", help="build levels 1..N (default 1, at most 8)")

    p = sub.add_parser("demo", parents=[demo_opts], formatter_class=_RAW,
                       help="the whole pipeline on the paper's figures, no input needed",
                       description=_d("Generate the paper's phantom (or read --input), make a key, encrypt, render the "
                                   "paper's figure set on a local Dask cluster, decrypt, and compare every image with "
                                   "its plaintext reference. Writes PNGs, a contact sheet, report.md and summary.json."),
                       epilog=DEMO_EPILOG)
    p.add_argument("--out", default="hevr-demo", metavar="DIR", help="output folder (default hevr-demo)")
    p.add_argument("--force", action="store_true",
                   help="replace files in DIR at the demo's names that an earlier demo run did not write")
    p.add_argument("--size", type=phantom_size_type, default=32, metavar="N",
                   help="phantom edge in voxels (default 32)")
    p.add_argument("--image", type=size_type, default=(48, 48), metavar="WxH", help="image size (default 48x48)")
    p.add_argument("--bits", type=bits_type, default=512, metavar="B", help="key size (default 512: demo only)")
    p.add_argument("--input", metavar="FILE", help="render this volume (any INPUT of 'hevr encrypt') instead of the phantom")
    p.add_argument("--brick", type=brick_type, metavar="N|BZ,BY,BX", help="brick edge (default: a third of the volume)")
    p.add_argument("--azimuth", type=finite_float, default=30.0, metavar="DEG", help="camera azimuth (default 30)")
    p.add_argument("--elevation", type=finite_float, default=20.0, metavar="DEG", help="camera elevation (default 20)")

    p = sub.add_parser("bench", parents=[_common(True, "2 (a 2-worker local cluster)")], formatter_class=_RAW,
                       help="benchmarks: the paper's Tables 1-3, limits, python-paillier, scaling",
                       description=_d("Reproduce the paper's Tables 1-3 (X-ray, storage, transfer function) with the "
                                   "paper's figures beside ours, measure against the limits (one modular "
                                   "multiplication, one fixed-base exponentiation), against python-paillier used "
                                   "naively, and how render time scales with workers, volume and key size. Writes "
                                   "markdown, raw JSON and a plot."),
                       epilog=BENCH_EPILOG)
    g = p.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="a smoke run of about 20 s (tiny volume and keys)")
    g.add_argument("--paper", action="store_true", help=f"the paper's setting: {PAPER_SIZE}^3, {PAPER_IMAGE}x{PAPER_IMAGE}, keys 64-3072 bits (~1.5 h)")
    p.add_argument("--out", metavar="DIR", help="output folder (default ./benchmarks if it exists, else .)")
    p.add_argument("--resume", action="store_true", help="keep the finished blocks of an earlier run of this setting")
    p.add_argument("--force", action="store_true",
                   help="start this setting afresh, replacing its results JSON, markdown and plot in --out")
    p.add_argument("--only", metavar="KINDS", help="comma-separated blocks: micro, t1, t2, t3, naive, scaling, pipeline")
    p.add_argument("--work", metavar="DIR", help="scratch folder for the encrypted stores (default: a temporary one)")
    p.add_argument("--report-only", action="store_true",
                   help="measure nothing: rewrite the markdown and plot from the existing results JSON")
    return parser


def _setup_logging(verbose: bool) -> logging.Handler:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("hevr: %(levelname)s: %(message)s" if not verbose
                                           else "%(asctime)s %(name)s %(levelname)s: %(message)s"))
    logger = logging.getLogger("hevr")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO if verbose else logging.WARNING)
    return handler


def _run(args: Any) -> int:
    if args.command == "bench":
        return cmd_bench(args)
    if args.command == "demo":
        return demo.cmd_demo(args)
    if args.command == "slice":
        return cmd_slice(args)
    if args.command == "pyramid":
        return cmd_pyramid(args)
    return getattr(cmds, f"cmd_{args.command.replace('-', '_')}")(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hevr`` console script; returns the exit code (module docstring)."""
    parser = build_parser()
    argv = join_negative_values(sys.argv[1:] if argv is None else argv, value_options(parser))  # --size -5x-5
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    if args.command is None:
        err_line("a command is required: keygen, convert-key, encrypt, render, recolour, slice, decrypt, info, upgrade-store, demo or bench "
                 "(see 'hevr --help')")
        return 2
    handler = _setup_logging(args.verbose)
    try:
        with warnings.catch_warnings():
            if not args.verbose:
                warnings.simplefilter("ignore", DeprecationWarning)
                warnings.simplefilter("ignore", FutureWarning)
            warnings.showwarning = show_warning
            code = _run(args)
            sys.stdout.flush()  # here, so that a reader gone away (`hevr info … | head -1`) is caught below
            return code
    except KeyboardInterrupt:
        err_line("interrupted")
        return 130
    except BrokenPipeError:  # the reader of stdout left: stop quietly, as Unix tools do
        silence_stdout()
        return 141  # 128 + SIGPIPE
    except Exception as exc:  # one line; the traceback only with --verbose
        if args.verbose:
            traceback.print_exc()
        err_line(cli_message(exc, args))
        return exit_code(exc, args)
    finally:
        logging.getLogger("hevr").removeHandler(handler)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
