"""Helpers shared by the command line's modules (:mod:`hevr.cli.main` and the commands).

The command line's own checks of the files it names (in its words: ``--out``, ``STORE``,
``FRAME``), its one-line messages on stderr, and small formatting helpers, among them
:func:`xyz` and :func:`wh`, the one axis order the CLI prints. The argparse value types are in
:mod:`hevr.cli.options`, key files in :mod:`hevr.cli.keys`, inputs in :mod:`hevr.cli.scan`, Dask
clients in :mod:`hevr.cli.cluster`. Nothing here ever prints secret-key material.

Light to import (the standard library, :mod:`hevr.errors` and two leaf modules): :mod:`hevr.cli.exits` and every
command's parser import it, ``hevr --version`` too.
"""

from __future__ import annotations

import errno
import io
import json
import numbers
import os
import sys
import time
from pathlib import Path
from typing import Any

from ..core.files import check_regular, fs_errors
from ..core.magic import IMAGE_MAGIC_PREFIX
from ..errors import (
    ExistingFileError,
    FileSystemError,
    MissingFileError,
    ParameterError,
)


class UsageError(ParameterError):
    """The command line asks for something that cannot be done as given, found by the CLI's own
    checks (an option combination, a named file of the wrong kind, an existing output); exit 2
    like argparse's errors (:mod:`hevr.cli.main`). The message starts with the option it names."""


# -- formatting --------------------------------------------------------------------------
class Timer:
    """``with Timer() as t: ...; t.seconds``"""

    def __enter__(self) -> Timer:
        self.start = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc: object) -> None:
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


def print_rows(rows: list[tuple[str, Any]]) -> None:
    """``hevr info``'s table: one ``key: value`` row a line, the values aligned."""
    w = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k + ':':<{w + 1}} {v}")


def plural(n: int, word: str, words: str | None = None) -> str:
    """``n`` and the noun in the number it needs, thousands separated.

    >>> plural(1, "brick"), plural(8, "brick"), plural(1234, "ciphertext")
    ('1 brick', '8 bricks', '1,234 ciphertexts')
    """
    return f"{n:,} {word if n == 1 else (words or word + 's')}"


def show_progress(args: Any, lines: bool = False) -> bool:
    """Progress bars unless --quiet, and only on a terminal (logs stay free of carriage returns);
    with ``lines`` also elsewhere, as a few ``hevr: INFO: …`` lines with the rate and the time
    left (``hevr encrypt``: minutes to hours of work that a log should show)."""
    return not getattr(args, "quiet", False) and (lines or sys.stderr.isatty())


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
    """The folder ``path`` goes into exists (else :class:`hevr.MissingFileError` naming ``option``,
    exit 2) and can be written (:func:`check_writable_folder`)."""
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise MissingFileError(option, "an existing directory", parent)
    check_writable_folder(parent, option)


def check_writable_folder(folder: Path, option: str = "--out") -> None:
    """The existing folder ``folder`` can be written into, before any work: else a
    :class:`hevr.FileSystemError` naming ``option``, the folder and the true cause — a read-only
    filesystem (``EROFS``) or no write permission (``EACCES``) — which fails the run (exit 1,
    as the same refusal would in the middle of it), not the command line."""
    err = None
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            err = errno.EROFS
    except (OSError, AttributeError):  # no statvfs (Windows): the write permission alone
        pass
    if err is None and not os.access(folder, os.W_OK):
        err = errno.EACCES
    if err is not None:
        raise FileSystemError(err, f"{option}: writing into", folder)


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
            head = fh.read(len(IMAGE_MAGIC_PREFIX))
    except OSError as exc:
        raise FileSystemError(exc.errno, f"{word}: reading", path, exc.strerror) from None
    if head != IMAGE_MAGIC_PREFIX:
        raise UsageError(f"{word}: expected {what}, got a file that is not one ({path})")
    return path


# -- the one axis order the CLI prints ---------------------------------------------------------
def _num(v: Any) -> str:
    """A size as printed: a float (numpy's too) in ``%g``, anything else as it is."""
    return f"{float(v):g}" if isinstance(v, numbers.Real) and not isinstance(v, numbers.Integral) else str(v)


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
