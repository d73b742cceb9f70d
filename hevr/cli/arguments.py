"""The arguments of the commands whose help needs nothing of the data path: ``keygen``,
``convert-key``, ``info``, ``upgrade-store`` and ``bench`` (their descriptions and examples too).

:mod:`hevr.cli.parser` calls one of these functions on the command's empty subparser, only for
the command being run (and for all of them when the whole parser is asked for). Its imports are
light (:mod:`hevr.paper`, :mod:`hevr.cli.options`: numpy and gmpy2 for the key-size caps), so that
``hevr info KEY`` starts without Dask or Zarr. The data-path commands' arguments, whose help
quotes transfer-function presets, views and modalities, are in :mod:`hevr.cli.render_arguments`.
"""

from __future__ import annotations

import argparse

from ..paper import PAPER_IMAGE, PAPER_SIZE
from .options import (
    add_general_options,
    add_scan_read_options,
    add_storage_option,
    bits_type,
)
from .parser import wrap

__all__ = [
    "BENCH_EPILOG",
    "bench_arguments",
    "convert_key_arguments",
    "info_arguments",
    "key_policy_arguments",
    "keygen_arguments",
    "upgrade_store_arguments",
]

# the paper's run, one line of the examples (two literals: the source stays within 120 columns)
_PAPER_BENCH = (
    "  hevr bench --paper              # the paper's tables: "
    f"{PAPER_SIZE}^3, {PAPER_IMAGE}x{PAPER_IMAGE} px, keys 64-3072 bits: ~1.5 h on 2 cores"
)

BENCH_EPILOG = f"""\
examples:
  hevr bench --quick              # ~20 s: 12^3 voxels, 16x16 px, keys 64-256 bits (CI smoke test)
  hevr bench                      # ~1 min: 32^3, 48x48 px, keys 256-1024 bits
{_PAPER_BENCH}
  hevr bench --paper --resume     # continue a stopped run (finished blocks are kept)
  hevr bench --only t1,micro      # some blocks only: micro, t1, t2, t3, naive, scaling, pipeline
  hevr bench --paper --report-only  # rewrite RESULTS.md and the plot from results-paper.json
  hevr bench --gpu                # on a GPU machine (~3 min): the cuda backend against cpu, then its throughput

writes, into --out (default: ./benchmarks if it exists, else .):
  RESULTS.md (--paper) or RESULTS-<setting>.md, results-<setting>.json, scaling-<setting>.png
  (an earlier run's files of the setting: continued with --resume, replaced with --force,
  else refused with exit 2)
"""


def keygen_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr keygen``: its description, examples and arguments."""
    add_general_options(p, dask=False)
    p.description = wrap(
        "Generate a Paillier key pair: the private key file (mode 0600) and the "
        "public key beside it (key.json -> key.pub.json)."
    )
    p.epilog = "example:\n  hevr keygen --bits 2048 --out key.json\n"
    p.add_argument(
        "--bits",
        type=bits_type,
        default=2048,
        help="modulus size n in bits (default 2048; smaller keys are for tests and demos only)",
    )
    p.add_argument("--out", default="key.json", metavar="KEY.json", help="private key file (default key.json)")
    p.add_argument("--force", action="store_true", help="overwrite existing key files")
    p.add_argument(
        "--format",
        choices=("hevr", "phe"),
        default="hevr",
        help="file format: hevr's (default) or python-paillier's pheutil JSON (phe)",
    )
    p.add_argument(
        "--no-require-tags",
        dest="require_tags",
        action="store_false",
        help="a key without the policy that every store of it carries tags (default: with it; hevr "
        "key-policy changes it later)",
    )


def key_policy_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr key-policy``: its description, examples and arguments."""
    add_general_options(p, dask=False)
    p.description = wrap(
        "Show or set the private key's policy: with --require-tags every store of this key must "
        "carry tags, so that a store without them (made with the public key only, or stripped by a "
        "server) is refused before it is rendered and never decrypts to an image; keys made by "
        "'hevr keygen' have it. The key file is rewritten in place (mode 0600, atomically)."
    )
    p.epilog = (
        "examples:\n  hevr key-policy key.json                   # show it\n"
        "  hevr key-policy key.json --require-tags    # an existing key opts in\n"
    )
    p.add_argument("key", metavar="KEY.json", help="the private key file (hevr's format)")
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--require-tags",
        dest="require_tags",
        action="store_true",
        default=None,
        help="every store of this key carries tags",
    )
    g.add_argument(
        "--no-require-tags",
        dest="require_tags",
        action="store_false",
        help="stores without tags are accepted (with a warning at each render)",
    )


def convert_key_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr convert-key``: its description, examples and arguments."""
    add_general_options(p, dask=False)
    p.description = wrap(
        "Write the key in KEY (either format; a private key stays private, mode 0600) "
        "in the other format. Every --key option reads both formats already."
    )
    p.epilog = (
        "examples:\n  hevr convert-key key.json --out phe-private.json            # hevr -> pheutil\n"
        "  hevr convert-key phe-private.json --out key.json --format hevr   # pheutil -> hevr\n"
        "  pheutil genpkey phe.json && hevr encrypt phantom:32 --key phe.json --out v.zarr\n"
    )
    p.add_argument("key", metavar="KEY", help="key file to read (hevr or pheutil, public or private)")
    p.add_argument("--out", required=True, metavar="FILE", help="key file to write")
    p.add_argument("--format", choices=("hevr", "phe"), default="phe", help="format to write (default phe)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out")


def info_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr info``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    add_storage_option(p)
    p.description = wrap(
        "Print what is public about a store, an encrypted frame, a key file or a "
        "volume file (its patient frame, modality and default value range), or the "
        "series a DICOM folder holds. Never prints secret-key material. A store gets "
        "a quick check (metadata, documents, completeness, chunk sizes: no ciphertext "
        "is read); --verify reads every brick back. Temporaries that an interrupted "
        "write left beside a store are named in a warning. Exit 1 if a check fails."
    )
    p.epilog = (
        "examples:\n  hevr info vol.zarr\n  hevr info vol.zarr --verify   # read every brick back\n"
        "  hevr info frame.hevr\n  hevr info key.pub.json\n"
        "  hevr info dicom/          # its series, for hevr encrypt --series UID\n"
    )
    p.add_argument("path", metavar="PATH")
    add_scan_read_options(p)  # a volume file: read as hevr encrypt reads it
    p.add_argument(
        "--verify",
        action="store_true",
        help="stores: also read every brick of every channel (and pyramid level) and check its "
        "digest and every ciphertext (0 < c < n², coprime to n); names each damaged brick by "
        "channel and index and exits 1 if any. Reads the whole store: one Dask task per brick "
        "with --scheduler/--workers. Frames and sums files are always checked in full",
    )


def upgrade_store_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr upgrade-store``: its description, examples and arguments."""
    add_general_options(p, dask=True)
    p.description = wrap(
        "Copy every brick of a format-1 store, unchanged and range-checked, into a new "
        "store with crc32c chunks and per-brick digests (docs/format.md). The old store is "
        "only read; no key is needed."
    )
    p.epilog = "example:\n  hevr upgrade-store old.zarr new.zarr\n"
    p.add_argument("src", metavar="OLD", help="the format-1 store")
    p.add_argument("dst", metavar="NEW", help="where the format-2 store goes (must not exist)")


def bench_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr bench``: its description, examples and arguments."""
    add_general_options(p, dask=True, workers_default="2 (a 2-worker local cluster)")
    p.description = wrap(
        "Reproduce the paper's Tables 1-3 (X-ray, storage, transfer function) with the "
        "paper's figures beside ours, measure against the limits (one modular "
        "multiplication, one fixed-base exponentiation), against python-paillier used "
        "naively, and how render time scales with workers, volume and key size. Writes "
        "markdown, raw JSON and a plot."
    )
    p.epilog = BENCH_EPILOG
    g = p.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="a smoke run of about 20 s (tiny volume and keys)")
    g.add_argument(
        "--paper",
        action="store_true",
        help=f"the paper's setting: {PAPER_SIZE}^3, {PAPER_IMAGE}x{PAPER_IMAGE}, keys 64-3072 bits (~1.5 h)",
    )
    p.add_argument("--out", metavar="DIR", help="output folder (default ./benchmarks if it exists, else .)")
    p.add_argument(
        "--gpu",
        action="store_true",
        help="prove the GPU backend here: every operation and a 64^3 render bit-identical to cpu, then "
        "2048-bit products/s and multi-exponentiation pairs/s; writes gpu.md and gpu.json naming the "
        "card (with --quick: 16^3 and fewer values); exit 1 on any mismatch",
    )
    p.add_argument(
        "--gpu-backend",
        metavar="NAME",
        default="cuda",
        help="the backend --gpu proves (default cuda; cuda-host runs the same kernels on the CPU)",
    )
    p.add_argument("--resume", action="store_true", help="keep the finished blocks of an earlier run of this setting")
    p.add_argument(
        "--force",
        action="store_true",
        help="start this setting afresh, replacing its results JSON, markdown and plot in --out",
    )
    p.add_argument(
        "--only", metavar="KINDS", help="comma-separated blocks: micro, t1, t2, t3, naive, scaling, pipeline"
    )
    p.add_argument("--work", metavar="DIR", help="scratch folder for the encrypted stores (default: a temporary one)")
    p.add_argument(
        "--report-only",
        action="store_true",
        help="measure nothing: rewrite the markdown and plot from the existing results JSON",
    )
