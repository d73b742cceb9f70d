"""Helpers shared by the command line (:mod:`hevr.cli.main`) and :mod:`hevr.cli.demo`.

Argument parsers that turn a bad value into one clear argparse error, the Dask
client/cluster context of a command, input loading (``phantom:N`` or a volume file),
and small formatting helpers. Nothing here ever prints secret-key material.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from distributed import Client, LocalCluster

from .._validate import MAX_BRICK_EDGE, MAX_STORE_DIGITS, MAX_VECTOR_DIMS
from ..crypto.keyfile import load_key
from ..crypto.keys import MAX_BITS, MIN_BITS, SECURE_BITS
from ..errors import InsecureKeyWarning, MissingFileError, ParameterError
from ..paper import PAPER_SIZE
from ..rendering.modes import parse_color
from ..rendering.planner import MAX_PIXELS_KEY, render_limits
from ..volume.loaders import load_volume
from ..volume.phantom import phantom

log = logging.getLogger("hevr.cli.main")


class UsageError(ParameterError):
    """An option combination argparse cannot check; reported like a usage error (exit 2)."""


# -- argparse value types ----------------------------------------------------------------
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


def vector_dims_type(text: str) -> int:
    """``--vector-dims``: an integer in [2, MAX_VECTOR_DIMS]."""
    v = _int_at_least(2, f"an integer in [2, {MAX_VECTOR_DIMS}] (the paper uses 4)")(text)
    if v > MAX_VECTOR_DIMS:
        raise argparse.ArgumentTypeError(f"expected an integer in [2, {MAX_VECTOR_DIMS}] (the paper uses 4), got {text!r}")
    return v


nonneg_int = _int_at_least(0, "a non-negative integer")


def digits_type(text: str) -> int:
    """``--digits``: decimal digits kept of float voxels, 0 .. MAX_STORE_DIGITS (the library's cap)."""
    v = nonneg_int(text)
    if v > MAX_STORE_DIGITS:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, {MAX_STORE_DIGITS}], got {text!r}")
    return v


def phantom_size_type(text: str) -> int:
    """A phantom edge N: an integer in [4, MAX_PHANTOM]."""
    try:
        v = int(text) if text.strip().isascii() else 0
    except ValueError:
        v = 0
    if not 4 <= v <= MAX_PHANTOM:
        raise argparse.ArgumentTypeError(f"expected a phantom edge N in [4, {MAX_PHANTOM}] voxels, got {text!r}")
    return v


def workers_type(text: str) -> int:
    """``--workers``: 0 .. MAX_WORKERS local worker processes."""
    v = nonneg_int(text)
    if v > MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"expected at most {MAX_WORKERS} worker processes, got {text!r}")
    return v


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

    nodes = []
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
        try:
            nodes.append((d, parse_color(col.strip())))
        except ParameterError:
            raise ParameterError(f"transfer-function node {i + 1} {item!r}: unknown colour {col.strip()!r} "
                                 "(use #rrggbb, #rgb or a CSS name such as red, blue, green)") from None
    return nodes


def tf_type(text: str) -> list[tuple[float, tuple[float, float, float]]]:
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


# -- inputs and keys -----------------------------------------------------------------------
def load_input(spec: str, spacing: Any = None) -> tuple[np.ndarray, tuple[float, float, float], str]:
    """``phantom:N`` (or ``phantom``) or any file/folder :func:`hevr.load_volume` reads.

    Returns (volume, spacing, description).
    """

    if spec == "phantom" or spec.startswith("phantom:"):
        size_text = spec.partition(":")[2] or str(PAPER_SIZE)
        try:
            size = phantom_size_type(size_text)
        except argparse.ArgumentTypeError:
            raise ParameterError(f"input {spec!r}: expected phantom:N with an integer N in [4, {MAX_PHANTOM}], "
                                 f"e.g. phantom:{PAPER_SIZE}") from None
        vol = phantom(size)
        return vol, tuple(spacing) if spacing else (1.0, 1.0, 1.0), f"phantom {size}^3 (uint8)"
    path = Path(spec).expanduser()
    if not path.exists():
        raise MissingFileError("--input", "a volume file, a DICOM folder or phantom:N", spec)
    vol, sp = load_volume(path, spacing=spacing)
    return vol, sp, f"{path.name} {'x'.join(str(s) for s in vol.shape[::-1])} ({vol.dtype})"


def public_key_path(path: str | Path) -> Path:
    """``key.json`` -> ``key.pub.json``; ``key`` -> ``key.pub``."""
    path = Path(path)
    if path.suffix == ".json":
        return path.with_name(path.stem + ".pub.json")
    return path.with_name(path.name + ".pub")


def read_key(path: str) -> Any:
    """Load a key file; insecure-size warnings are left to keygen/info (bits are shown there)."""


    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        return load_key(path)


def key_label(pub: Any) -> str:
    weak = " (NOT secure: < 2048 bits)" if pub.bits < SECURE_BITS else ""
    return f"{pub.bits}-bit{weak}, fingerprint {pub.fingerprint}"


# -- Dask --------------------------------------------------------------------------------
@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """Join ``scheduler``, or start ``workers`` local worker processes, or use Dask's default.

    Yields the ``distributed.Client`` (or None); closes what it opened.
    """
    if scheduler:

        log.info("connecting to the Dask scheduler at %s", scheduler)
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise OSError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
    elif workers:

        log.info("starting a local Dask cluster: %d worker processes, 1 thread each", workers)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
        try:
            client = Client(cluster)
            try:
                yield client
            finally:
                client.close()
        finally:
            cluster.close()
    else:
        yield None


def describe_client(client: Any) -> str:
    if client is None:
        return "Dask's default (threaded) scheduler"
    try:
        n = len(client.scheduler_info().get("workers", {}))
    except Exception:  # pragma: no cover - informational only
        n = "?"
    return f"Dask cluster {client.scheduler.address} ({n} workers)"


# -- formatting --------------------------------------------------------------------------
class Timer:
    """``with Timer() as t: ...; t.seconds``"""

    def __enter__(self) -> "Timer":
        self.start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc: Any) -> None:
        self.seconds = time.perf_counter() - self.start


def human_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"  # pragma: no cover


def disk_usage(path: str | Path) -> int:
    path = Path(path)
    if path.is_file():
        return path.stat().st_size
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def table(rows: list[list[Any]], header: list[str]) -> str:
    """A plain-text table (right-aligned numbers)."""
    cells = [[str(c) for c in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = []
    for j, r in enumerate(cells):
        lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        if j == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def show_progress(args: Any) -> bool:
    """Progress bars unless --quiet, and only on a terminal (logs stay free of carriage returns)."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


def err_line(message: str) -> None:
    """One line on stderr, ``hevr: error: …``."""
    sys.stderr.write("hevr: error: " + " ".join(str(message).split()) + "\n")
    sys.stderr.flush()


def warn_line(message: str) -> None:
    sys.stderr.write("hevr: warning: " + " ".join(str(message).split()) + "\n")
    sys.stderr.flush()


def check_writable_dir(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise MissingFileError("--out", "an existing directory", parent)
    if not os.access(parent, os.W_OK):
        raise PermissionError(13, "directory is not writable", str(parent))
