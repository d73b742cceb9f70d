"""Helpers shared by the command line (:mod:`hevr.cli.main`) and :mod:`hevr.cli.demo`.

The Dask client/cluster context of a command, input and key loading (``phantom:N`` or a
volume file), the command line's own checks of the files it names (in its words: ``--key``,
``STORE``), and small formatting helpers, among them :func:`xyz` and :func:`wh`, the one axis
order the CLI prints. The argparse value types are in :mod:`hevr.cli.options`. Nothing here
ever prints secret-key material.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from distributed import Client, LocalCluster

from .._files import check_regular, fs_errors
from .._image_header import MAGIC_PREFIX
from ..crypto.keyfile import load_key
from ..crypto.keys import SECURE_BITS, PrivateKey
from ..errors import (
    ExistingFileError,
    FileSystemError,
    InsecureKeyWarning,
    MissingFileError,
    ParameterError,
    VolumeFormatError,
)
from ..paper import PAPER_SIZE
from ..rendering.modes import parse_color
from ..volume.loaders import read_scan
from ..volume.phantom import phantom
from ..volume.samples import SAMPLES, sample_scan
from ..volume.scan import Scan
from .options import MAX_PHANTOM, phantom_size_type

log = logging.getLogger("hevr.cli.main")


class UsageError(ParameterError):
    """The command line asks for something that cannot be done as given, found by the CLI's own
    checks (an option combination, a named file of the wrong kind, an existing output); exit 2
    like argparse's errors (:mod:`hevr.cli.main`). The message starts with the option it names."""


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
    """:func:`load_scan` reduced to (volume, spacing, description)."""
    scan, what = load_scan(spec, spacing)
    return scan.volume, scan.spacing, what


def load_scan(spec: str, spacing: Any = None, **read: Any) -> tuple[Scan, str]:
    """``phantom:N`` (or ``phantom``), ``sample:mri`` (:func:`hevr.sample_scan`) or any
    file/folder :func:`hevr.read_scan` reads.

    ``read``: read_scan's ``series``, ``volume``, ``allow_uneven``, ``oblique``. Returns the
    scan and a description; its frame, modality and origin are logged at INFO. Errors name
    the volume ``input``: each command says which of its arguments that is (``INPUT``,
    ``--input``, ``PATH``).
    """

    if spec == "phantom" or spec.startswith("phantom:"):
        size_text = spec.partition(":")[2] or str(PAPER_SIZE)
        try:
            size = phantom_size_type(size_text)
        except argparse.ArgumentTypeError:
            raise UsageError(f"input: expected phantom:N with an integer N in [4, {MAX_PHANTOM}] "
                             f"(e.g. phantom:{PAPER_SIZE}), got {spec!r}") from None
        given = [k for k, v in read.items() if v not in (None, False, "refuse")]
        if given:
            raise UsageError(f"{', '.join(given)}: expected a scan file or folder as INPUT, got {spec!r}")
        vol = phantom(size)
        sp = tuple(float(v) for v in spacing) if spacing else (1.0, 1.0, 1.0)
        return Scan(vol, sp, source=spec), f"phantom, {xyz(vol.shape)} voxels (uint8)"  # type: ignore[arg-type]
    if spec.startswith("sample:") and not Path(spec).exists():  # a real scan an installed package ships
        name = spec.partition(":")[2]
        if name not in SAMPLES:
            raise UsageError(f"input: expected sample:NAME with NAME one of {', '.join(SAMPLES)}, got {spec!r}")
        path = sample_scan(name)
    else:
        path = Path(spec).expanduser()
    if not path.exists():
        raise MissingFileError("input", "a volume file, a DICOM folder, phantom:N or sample:mri", spec)
    try:
        scan = read_scan(path, spacing=spacing, **read)
    except MissingFileError as exc:  # a file the input refers to (an .nhdr's detached data file)
        raise VolumeFormatError(f"input: {spec} refers to {exc.filename}, which does not exist") from None
    log.info("%s: %s, modality %s, origin %s mm", spec, "RAS+ patient frame" if scan.frame else "axes as stored "
             "(no patient frame recorded)", scan.modality or "not recorded", scan.origin)
    vol = scan.volume
    return scan, f"{path.name}, {xyz(vol.shape)} voxels ({vol.dtype})"


def public_key_path(path: str | Path) -> Path:
    """``key.json`` -> ``key.pub.json``; ``key`` -> ``key.pub``."""
    path = Path(path)
    if path.suffix == ".json":
        return path.with_name(path.stem + ".pub.json")
    return path.with_name(path.name + ".pub")


def read_key(path: str, private: bool = False) -> Any:
    """Load a key file; insecure-size warnings are left to keygen/info (bits are shown there).

    ``private``: refuse a public key (``key: expected a private key file, …``). Errors name
    the ``key``, as :func:`hevr.load_key` does; each command says which argument that is.
    """
    if Path(path).expanduser().is_dir():
        raise UsageError(f"key: expected a key file, got a folder ({path})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        key = load_key(Path(path).expanduser())
    if private and not isinstance(key, PrivateKey):
        raise UsageError(f"key: expected a private key file, got a public key ({path})")
    return key


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
            raise OSError(f"--scheduler: cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
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
    try:
        board = f", dashboard {client.dashboard_link}" if client.dashboard_link else ""
    except Exception:  # pragma: no cover - no dashboard (bokeh missing, or disabled)
        board = ""
    return f"Dask cluster {client.scheduler.address} ({n} workers{board})"


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


def silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush into the closed pipe
    prints no "Exception ignored … BrokenPipeError"."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):  # no real file behind stdout
        pass


def err_line(message: str) -> None:
    """One line on stderr, ``hevr: error: …``."""
    sys.stderr.write("hevr: error: " + " ".join(str(message).split()) + "\n")
    sys.stderr.flush()


def warn_line(message: str) -> None:
    sys.stderr.write("hevr: warning: " + " ".join(str(message).split()) + "\n")
    sys.stderr.flush()


def show_warning(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
    """``warnings.showwarning`` of a command: one ``hevr: warning:`` line."""
    warn_line(f"{message}")


# -- what the command line names, checked in its words -----------------------------------------
def check_writable_dir(path: Path, option: str = "--out") -> None:
    """The folder ``path`` goes into exists and is writable (else a usage error naming ``option``)."""
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise MissingFileError(option, "an existing directory", parent)
    if not os.access(parent, os.W_OK):
        raise UsageError(f"{option}: expected a writable directory, got {parent} (permission denied)")


def check_output_file(path: Path, option: str = "--out", suffix: str | None = None) -> None:
    """``path`` can be written as a file: not a folder, in a writable folder, ending in ``suffix``
    (a name the OS refuses, e.g. too long: :class:`hevr.FileSystemError` naming ``option``)."""
    with fs_errors(f"{option}: checking", path):
        if path.is_dir():
            raise UsageError(f"{option}: expected a file name, got a folder ({path})")
        if suffix and path.suffix.lower() != suffix:
            raise UsageError(f"{option}: expected a {suffix} file name, got {path}")
        check_writable_dir(path, option)


def check_new_file(path: Path, option: str = "--out", suffix: str | None = None, *, force: bool = False) -> None:
    """:func:`check_output_file`, and nothing at ``path`` unless ``force``: an existing file is
    an :class:`hevr.ExistingFileError` naming ``option`` (exit 2; the message says ``--force``)."""
    check_output_file(path, option, suffix)
    if not force and (path.exists() or path.is_symlink()):
        raise ExistingFileError(option, path)


def check_store_path(path: Path, word: str) -> Path:
    """``path`` names an hevr encrypted volume store: a folder whose zarr.json has hevr metadata.

    Anything else is the wrong kind of file (a usage error naming ``word``); a store that has
    hevr metadata but fails hevr's own checks is left to :func:`hevr.open_volume` (corrupt data).
    """
    what = "an encrypted volume store (a folder made by 'hevr encrypt')"
    if not path.exists():
        raise MissingFileError(word, what, path)
    if not path.is_dir():
        raise UsageError(f"{word}: expected {what}, got a file ({path})")
    meta = path / "zarr.json"
    if meta.exists() and not meta.is_file():  # a FIFO there: hevr.open_volume names the damage (never opened here)
        return path
    if not meta.is_file():
        raise UsageError(f"{word}: expected {what}, got a folder without zarr.json ({path})")
    try:
        doc = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return path  # unreadable metadata of what may be a store: hevr.open_volume names the damage
    attrs = doc.get("attributes") if isinstance(doc, dict) else None
    if not (isinstance(attrs, dict) and "hevr" in attrs):
        raise UsageError(f"{word}: expected {what}, got a Zarr folder without hevr metadata ({path})")
    return path


def check_frame_path(path: Path, word: str) -> Path:
    """``path`` names an encrypted image file (.hevr): it exists, is a file, starts with its magic.
    The rest (version, header, checksum) is :func:`hevr.load_image`'s."""
    what = "an encrypted image (a .hevr file made by 'hevr render')"
    if not path.exists():
        raise MissingFileError(word, what, path)
    if path.is_dir():
        raise UsageError(f"{word}: expected {what}, got a folder ({path})")
    check_regular(path, word, what)  # a FIFO or a device: NotRegularFileError, never a blocked open
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(MAGIC_PREFIX))
    except OSError as exc:
        raise FileSystemError(exc.errno, f"{word}: reading", path, exc.strerror) from None
    if head != MAGIC_PREFIX:
        raise UsageError(f"{word}: expected {what}, got a file that is not one ({path})")
    return path


# -- the one axis order the CLI prints ---------------------------------------------------------
def _num(v: Any) -> str:
    return f"{float(v):g}" if isinstance(v, (float, np.floating)) else str(v)


def xyz(zyx: Any, sep: str = "×") -> str:
    """Three sizes given in array order (z, y, x) -> ``"x×y×z = 103×94×161"``.

    Every size the CLI prints (volumes, bricks, grids; spacing with ``sep=", "``) goes through
    here: world order x, y, z, labelled, the order of ``--spacing SX,SY,SZ`` and ``--size WxH``.

    >>> xyz((161, 94, 103))
    'x×y×z = 103×94×161'
    >>> xyz((2.5, 1.0, 1.0), sep=", ")
    'x, y, z = 1, 1, 2.5'
    """
    z, y, x = (_num(v) for v in zyx)
    return f"x{sep}y{sep}z = {x}{sep}{y}{sep}{z}"


def wh(width: Any, height: Any) -> str:
    """An image size, the order of ``--size WxH``: ``wh(20, 16)`` -> ``"W×H = 20×16"``."""
    return f"W×H = {_num(width)}×{_num(height)}"
