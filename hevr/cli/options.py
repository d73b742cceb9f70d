"""argparse value types of the ``hevr`` command line (:mod:`hevr.cli.parser`), and the option
groups several commands share (general options, ``--storage-option``, how a scan is read).

Each type turns a bad value into one argparse error, ``argument --bits: expected …, got '…'``
(exit 2), before anything is loaded or started; the caps (``MAX_WORKERS``, ``MAX_PHANTOM``,
``MAX_PRECISION``, the library's own limits) live here.

Light to import (numpy and gmpy2 for the library's caps; no Dask, Zarr or plaintext readers):
``hevr info KEY`` builds its parser from here. The types whose checks or help quote the render
side's tables (image sizes, colours and transfer-function presets, pyramid levels, views,
modalities) are in :mod:`hevr.cli.render_options`.

>>> storage_option_type("endpoint_url=http://127.0.0.1:9000"), storage_option_type("anon=true")
(('endpoint_url', 'http://127.0.0.1:9000'), ('anon', True))
"""

from __future__ import annotations

import argparse
import json
import math
import os
from typing import Any

from ..core.validate import MAX_BRICK_EDGE, MAX_STORE_DIGITS, MAX_VECTOR_DIMS
from ..crypto.keys import MAX_BITS, MIN_BITS, SECURE_BITS

# Environment variable: a JSON object of fsspec options, beside --storage-option (hevr.cli.storage).
STORAGE_OPTIONS_ENV = "HEVR_STORAGE_OPTIONS"


# -- value types ----------------------------------------------------------------
def bits_type(text: str) -> int:
    """``--bits``: an even key size in [MIN_BITS, MAX_BITS]."""
    try:
        bits = int(text)
    except ValueError:
        bits = -1
    if bits < MIN_BITS or bits > MAX_BITS or bits % 2:
        raise argparse.ArgumentTypeError(
            f"expected an even number of bits in [{MIN_BITS}, {MAX_BITS}] (e.g. {SECURE_BITS}), got {text!r}"
        )
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


def int_range(lo: int, hi: int, expected: str):
    """An argparse type: an integer in [lo, hi]; anything else names ``expected`` and the text."""

    def parse(text: str) -> int:
        v = _int_at_least(lo, expected)(text)
        if v > hi:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return parse


# --digits: decimal digits kept of float voxels (the library's cap); --precision: of the normalisation
vector_dims_type = int_range(2, MAX_VECTOR_DIMS, f"an integer in [2, {MAX_VECTOR_DIMS}] (the paper uses 4)")
digits_type = int_range(0, MAX_STORE_DIGITS, f"an integer in [0, {MAX_STORE_DIGITS}]")
precision_type = int_range(0, MAX_PRECISION, f"an integer in [0, {MAX_PRECISION}]")


def phantom_size_type(text: str) -> int:
    """A phantom edge N: an integer in [4, MAX_PHANTOM]."""
    try:
        v = int(text) if text.strip().isascii() else 0
    except ValueError:
        v = 0
    if not 4 <= v <= MAX_PHANTOM:
        raise argparse.ArgumentTypeError(f"expected a phantom edge N in [4, {MAX_PHANTOM}] voxels, got {text!r}")
    return v


# --workers: local worker processes beyond a few per core only compete for the cores (1,000 on 2
# cores never finished); past WORKERS_PER_CORE × os.cpu_count() the count is refused.
WORKERS_PER_CORE = 4


def max_workers() -> int:
    """The most ``--workers`` this machine takes: :data:`WORKERS_PER_CORE` per CPU core (at least
    that many), at most :data:`MAX_WORKERS`."""
    return min(MAX_WORKERS, WORKERS_PER_CORE * max(1, os.cpu_count() or 1))


def workers_type(text: str) -> int:
    """``--workers N``: an integer in [0, :func:`max_workers`], else a message that says what this machine has."""
    cores, limit = os.cpu_count(), max_workers()
    has = f"this machine has {cores} CPU core{'s' if cores != 1 else ''}" if cores else "its core count is unknown"
    return int_range(
        0, limit, f"at most {limit} worker processes (0: none; {WORKERS_PER_CORE} per CPU core, and {has})"
    )(text)


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


def storage_option_type(text: str) -> tuple[str, Any]:
    """argparse type of ``--storage-option KEY=VALUE`` (:mod:`hevr.cli.storage`)."""
    key, sep, value = str(text).partition("=")
    key = key.strip()
    if not sep or not key or not key.replace("_", "a").replace("-", "a").isalnum():
        raise argparse.ArgumentTypeError(
            f"expected KEY=VALUE with a KEY of letters, digits and '_' "
            f"(e.g. endpoint_url=http://127.0.0.1:9000), got {key or 'no key'!r}"
        )
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


# -- option groups ----------------------------------------------------------------------------
def add_general_options(
    p: argparse.ArgumentParser, dask: bool, workers_default: str = "Dask's default threaded scheduler"
) -> None:
    """Every command's ``-v``/``-q``; with ``dask``, ``--scheduler`` and ``--workers`` too."""
    g = p.add_argument_group("general options")
    if dask:
        g.add_argument(
            "--scheduler",
            metavar="ADDRESS",
            help="join a running Dask cluster, e.g. tcp://10.0.0.5:8786 (store paths must be "
            "reachable from its workers)",
        )
        g.add_argument(
            "--own-cluster",
            action="store_true",
            help="declare the --scheduler cluster yours: its scheduler and workers may run code in this "
            "process (Dask unpickles what they send), so a private key may be used beside it; "
            "without it a private key is refused with another party's cluster (render there "
            "with --server). Env HEVR_OWN_CLUSTER=ADDRESS[,ADDRESS] does the same",
        )
        g.add_argument(
            "--workers",
            type=workers_type,
            metavar="N",
            help="start a local Dask cluster of N worker processes (1 thread each) for this "
            f"command (0: none; at most {WORKERS_PER_CORE} per CPU core); default: {workers_default}",
        )
    g.add_argument("-v", "--verbose", action="store_true", help="INFO logging, and tracebacks on errors")
    g.add_argument(
        "-q", "--quiet", action="store_true", help="no progress bars (they are only drawn on a terminal anyway)"
    )


def add_storage_option(p: argparse.ArgumentParser) -> None:
    """``--storage-option``: stores, frames and sums on object storage (:mod:`hevr.cli.storage`)."""
    g = p.add_argument_group("object storage")
    g.add_argument(
        "--storage-option",
        dest="storage_option",
        action="append",
        type=storage_option_type,
        metavar="KEY=VALUE",
        help="an fsspec option of the URL's filesystem (repeatable), e.g. endpoint_url=http://host:9000, "
        f"anon=true, profile=NAME; JSON values are parsed. Env {STORAGE_OPTIONS_ENV}: a JSON object "
        "of options. STORE, FRAME and SUMS may be URLs (s3://, gs://, az://, file://)",
    )


def add_scan_read_options(p: argparse.ArgumentParser) -> None:
    """How a scan is read — ``hevr encrypt`` and ``hevr info`` alike, so that info describes
    exactly what encrypt reads."""
    p.add_argument(
        "--series",
        metavar="UID",
        help="DICOM: the series to read from a folder holding several "
        "(a SeriesInstanceUID, a unique prefix or a SeriesNumber; 'hevr info FOLDER' lists them)",
    )
    p.add_argument(
        "--volume",
        type=int,
        metavar="INDEX",
        help="4-D NIfTI/NRRD/TIFF/OME-Zarr: the time point or component to encrypt",
    )
    p.add_argument(
        "--allow-uneven",
        action="store_true",
        help="DICOM: accept unevenly spaced slices (read at their median spacing)",
    )
    p.add_argument(
        "--oblique",
        choices=("refuse", "snap"),
        default="refuse",
        help="a scan tilted more than 1 degree off the patient axes: refuse (default; hevr does not "
        "resample) or snap to the nearest axes",
    )
