"""The arguments of the owner's data-path commands: ``encrypt``, ``pyramid`` and ``demo`` (their
descriptions and examples too); those of the key holder's (``render``, ``recolour``, ``slice``,
``decrypt``) are in :mod:`hevr.cli.render_arguments`.

:mod:`hevr.cli.parser` calls one of these functions on the command's empty subparser, only for
the command being run. Their help and checks quote the render side's tables (transfer-function
presets, views, modalities, pyramid levels: :mod:`hevr.cli.render_options`), which is why they are
not in :mod:`hevr.cli.arguments` with the commands that start without them.
"""

from __future__ import annotations

import argparse

from ..paper import (
    PAPER_IMAGE,
    PAPER_SIZE,
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
    range_type,
    vector_dims_type,
)
from .parser import wrap
from .render_options import (
    add_encrypt_scan_options,
    levels_type,
    size_type,
)

__all__ = ["DEMO_EPILOG", "PYRAMID_EPILOG", "demo_arguments", "encrypt_arguments", "pyramid_arguments"]

PYRAMID_EPILOG = """\
examples:
  hevr pyramid vol.zarr                  # level 1: 8x fewer voxels
  hevr pyramid vol.zarr --levels 3 --workers 2
  hevr render vol.zarr --out preview.hevr --level 2   # a quick preview, same camera options

A level's voxel is the mean of its 2x2x2 children (edge voxels repeated at odd sizes); levels
already built are kept, an interrupted level is finished. The store gains levels/L arrays and
OME-Zarr multiscales metadata; no key is needed and nothing about the data is revealed.
"""

# the paper's run, one line of the examples (two literals: the source stays within 120 columns)
_PAPER_DEMO = (
    f"  hevr demo --size {PAPER_SIZE} --image {PAPER_IMAGE}x{PAPER_IMAGE} --bits 2048   "
    "# the paper's setting: ~25 min on 2 cores (README)"
)

DEMO_EPILOG = f"""\
examples:
  hevr demo                                   # 15-25 s on a 2-core laptop (32^3, 48x48 px, 512-bit key)
  hevr demo --out figs --size 64 --image 96x96
{_PAPER_DEMO}
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
