"""How an error escaping a ``hevr`` command is reported: its exit status and its message.

One rule for every command (also in :mod:`hevr.cli.main`'s docstring and ``hevr --help``):
exit 2 when the command line asks for something that cannot be done as given
(:data:`USAGE_ERRORS`, and a plain ``OSError`` "missing / exists / is (not) a folder" about a
path the command line names), exit 1 when the data or the run failed (``CorruptStoreError``,
``IncompleteStoreError``, ``CorruptVolumeError``, ``IntegrityError``, ``PlaintextOverflowError``,
``MissingDependencyError``, ``MemoryLimitError``, I/O errors, anything unexpected), 130 when
interrupted.

Library messages name Python parameters (``vol: expected …``); :func:`cli_message` rewrites
that leading name with the option or argument it came from, per command (:data:`CLI_NAMES`),
puts the argument first when a message starts with a file name (:data:`CLI_SUBJECTS`), and
respells Python phrases inside it (:data:`CLI_PHRASES`). A new command adds its entries there.
"""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path
from typing import Any

from ..errors import (
    CorruptVolumeError,
    ExistingFileError,
    ForeignClusterError,
    HevrError,
    IntegrityError,
    InvalidKeyError,
    KeyMismatchError,
    MissingDependencyError,
    MissingFileError,
    NotRegularFileError,
    ParameterError,
    PlaintextOverflowError,
    RenderPlanError,
    StoreError,
    StoreExistsError,
    VolumeFormatError,
)
from .util import UsageError

__all__ = [
    "cli_phrases",
    "interrupted_message",
    "EXIT_RULE",
    "USAGE_ERRORS",
    "DATA_ERRORS",
    "CLI_NAMES",
    "CLI_SUBJECTS",
    "CLI_PHRASES",
    "exit_code",
    "cli_message",
]

EXIT_RULE = """\
exit status (every command):
  0    done (hevr info: and every check passed)
  2    the command line asks for something that cannot be done as given: a bad option value
       or combination, a named file that is missing or of the wrong kind, an output that
       exists without --force/--overwrite, a key of another volume, a render refused by the
       planner (the message names the option to change), the private key beside another
       party's Dask scheduler (--own-cluster if it is yours)
  1    the data or the run failed: a corrupt, tampered or incomplete store, frame or scan, an
       integrity check, an I/O error (a full disk, an output folder on a read-only filesystem
       or without write permission), a missing optional dependency, a crashed worker
  130  interrupted
"""

# Exit 2: the command line asks for something that cannot be done as given (module docstring).
# Everything else that escapes a command is exit 1: the data or the run failed.
USAGE_ERRORS: tuple[type[BaseException], ...] = (
    UsageError,
    ParameterError,
    MissingFileError,
    NotRegularFileError,
    ExistingFileError,
    StoreExistsError,
    KeyMismatchError,
    RenderPlanError,
    InvalidKeyError,
    VolumeFormatError,
    ForeignClusterError,
)
# Subclasses of a usage error that are failed data all the same (exit 1).
DATA_ERRORS: tuple[type[BaseException], ...] = (CorruptVolumeError,)
# An OSError about a path the command line names: the path is missing or of the wrong kind.
_PATH_ERRNOS = frozenset({errno.ENOENT, errno.EEXIST, errno.EISDIR, errno.ENOTDIR})

_EVERY = {"workers": "--workers", "scheduler": "--scheduler", "client": "--scheduler"}
# Per command: the library's parameter names (and the CLI helpers' "input", "key") -> the option
# or argument the value came from. An escaping error's leading "name: " is rewritten with it; a
# command's argparse dest is listed too (a path it names is matched to its option).
CLI_NAMES: dict[str, dict[str, str]] = {
    "keygen": {"bits": "--bits", "out": "--out", "path": "--out", "overwrite": "--force"},
    "key-policy": {"key": "KEY.json", "path": "KEY.json"},
    "convert-key": {"key": "KEY", "out": "--out", "path": "--out", "overwrite": "--force", "format": "--format"},
    "encrypt": {
        "gradient": "--gradient",
        "verifiable": "--verifiable",
        "input": "INPUT",
        "vol": "INPUT",
        "data": "INPUT",
        "load_volume": "INPUT",
        "key": "--key",
        "public_key": "--key",
        "private_key": "--key",
        "out": "--out",
        "path": "--out",
        "brick": "--brick",
        "spacing": "--spacing",
        "value_range": "--value-range",
        "digits": "--digits",
        "vector_dims": "--vector-dims",
        "scalar": "--no-scalar",
        "overwrite": "--overwrite",
        "resume": "--resume",
        "series": "--series",
        "volume": "--volume",
        "modality": "--modality",
        "oblique": "--oblique",
        "allow_uneven": "--allow-uneven",
        "read_scan": "--series, --allow-uneven",
        "layout": "--layout",
        "pack_axis": "--pack-axis",
        "levels": "--levels",
    },
    "render": {
        "gradient": "--gradient",
        "verify": "--verify",
        "store": "STORE",
        "path": "STORE",
        "ev": "STORE",
        "out": "--out",
        "mode": "--mode",
        "nodes": "--tf",
        "density": "--density",
        "sampling": "--sampling",
        "camera": "--size",
        "width": "--size",
        "height": "--size",
        "view_angle": "--view-angle",
        "parallel": "--parallel",
        "step": "--step",
        "precision": "--precision",
        "pack": "--no-pack",
        "keep_sums": "--keep-sums",
        "level": "--level",
        "view": "--view",
        "azimuth": "--azimuth",
        "elevation": "--elevation",
        "overwrite": "--force",
        "finish": "--finish",
    },
    "pyramid": {"store": "STORE", "path": "STORE", "ev": "STORE", "levels": "--levels", "level": "--levels"},
    "recolour": {
        "gradient": "--gradient",
        "sums": "SUMS",
        "path": "SUMS",
        "out": "--out",
        "mode": "--mode",
        "nodes": "--tf",
        "density": "--density",
        "precision": "--precision",
        "pack": "--no-pack",
        "overwrite": "--force",
        "finish": "--finish",
    },
    "slice": {
        "gradient": "--gradient",
        "verify": "--verify",
        "store": "STORE",
        "path": "STORE",
        "ev": "STORE",
        "out": "--out",
        "mode": "--mode",
        "nodes": "--tf",
        "density": "--density",
        "sampling": "--sampling",
        "k": "--axial",
        "j": "--coronal",
        "i": "--sagittal",
        "axial": "--axial",
        "coronal": "--coronal",
        "sagittal": "--sagittal",
        "oblique": "--oblique",
        "center": "--oblique",
        "normal": "--oblique",
        "v": "--oblique",
        "camera": "--size",
        "plane": "--size",
        "width": "--size",
        "height": "--size",
        "pixel_spacing": "--pixel-spacing",
        "slab": "--slab",
        "slab_step": "--slab-step",
        "step": "--slab-step",
        "precision": "--precision",
        "pack": "--no-pack",
        "overwrite": "--force",
        "finish": "--finish",
    },
    "decrypt": {
        "frame": "FRAME",
        "path": "FRAME",
        "image": "FRAME",
        "key": "--key",
        "private_key": "--key",
        "out": "--out",
        "npy": "--npy",
        "window": "--window",
        "overwrite": "--force",
        "mode": "--mode",
        "nodes": "--tf",
        "density": "--density",
        "value_range": "--value-range",
    },
    "info": {
        "path": "PATH",
        "input": "PATH",
        "key": "PATH",
        "image": "PATH",
        "series": "--series",
        "volume": "--volume",
        "oblique": "--oblique",
        "allow_uneven": "--allow-uneven",
        "read_scan": "--series, --allow-uneven",
    },
    "upgrade-store": {"src": "OLD", "dst": "NEW"},
    "known": {"key": "--key", "private_key": "--key", "path": "FILE", "file": "FILE", "overwrite": "--force"},
    "demo": {
        "input": "--input",
        "vol": "--input",
        "load_volume": "--input",
        "out": "--out",
        "bits": "--bits",
        "brick": "--brick",
        "camera": "--image",
        "width": "--image",
        "height": "--image",
        "size": "--size",
        "overwrite": "--force",
    },
    "bench": {"only": "--only", "out": "--out", "work": "--work", "resume": "--resume", "overwrite": "--force"},
}
# A message that starts with a file name instead: the argument that named that file, by error class.
CLI_SUBJECTS: dict[str, dict[type, str]] = {
    "encrypt": {
        InvalidKeyError: "--key",
        KeyMismatchError: "--key",
        VolumeFormatError: "INPUT",
        MissingDependencyError: "INPUT",
        StoreError: "--out",
    },
    "convert-key": {InvalidKeyError: "KEY"},
    "render": {StoreError: "STORE"},
    "pyramid": {StoreError: "STORE"},
    "recolour": {StoreError: "SUMS", IntegrityError: "SUMS"},
    "slice": {StoreError: "STORE"},
    "decrypt": {
        InvalidKeyError: "--key",
        KeyMismatchError: "--key",
        StoreError: "FRAME",
        IntegrityError: "FRAME",
        PlaintextOverflowError: "FRAME",
    },
    "info": {HevrError: "PATH"},
    "upgrade-store": {StoreError: "OLD"},
    "demo": {VolumeFormatError: "--input", MissingDependencyError: "--input"},
}
# Python spellings inside library messages, as the CLI spells them ("*": every command).
# how a scan is read: hevr encrypt and hevr info take the same options (cli/scan.py)
_SCAN_PHRASES = {
    "pass series=UID (CLI --series UID;": "pass --series UID (",
    "volume=i (CLI --volume i)": "--volume i",
    "volume= only applies": "--volume only applies",
    "oblique='snap' (CLI --oblique snap)": "--oblique snap",
    "allow_uneven=True": "--allow-uneven",
    "series and allow_uneven only apply to DICOM": "they only apply to a DICOM INPUT",
}

CLI_PHRASES: dict[str, dict[str, str]] = {
    "*": {
        "encrypt_volume(..., resume=True)": "'hevr encrypt … --resume'",
        "hevr.encrypt_volume(..., vector_dims=k, gradient=True)": "'hevr encrypt … --vector-dims K --gradient'",
        "a store encrypted with gradient=True": "a store encrypted with --gradient",
        "with gradient=True (the gradient channel": "with --gradient (the gradient channel",
        "vector_dims=k as well": "--vector-dims K as well",
    },
    "render": {"use a larger step or a smaller image": "use a larger --step or a smaller --size"},
    "encrypt": _SCAN_PHRASES,
    "info": _SCAN_PHRASES,  # reads a scan with encrypt's options
    "slice": {"use a larger step or a smaller image": "use a larger --slab-step, a smaller --slab or --size"},
}
_LEADING = re.compile(r"([A-Za-z_]\w*(?:\[\d+\])?(?:(?:, |/)[A-Za-z_]\w*(?:\[\d+\])?)*): ")


def _message(exc: BaseException) -> str:
    if isinstance(exc, OSError) and not isinstance(exc, HevrError) and exc.filename and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    text = str(exc) or type(exc).__name__
    if not isinstance(exc, (HevrError, OSError, ValueError)):
        text = f"{type(exc).__name__}: {text} (run with --verbose for the traceback)"
    return text


def _named_path(exc: BaseException, args: Any, names: dict[str, str]) -> str | None:
    """The option/argument whose value is the path a plain OSError is about, if any."""
    filename = getattr(exc, "filename", None) if isinstance(exc, OSError) and not isinstance(exc, HevrError) else None
    if not filename:
        return None
    for dest, word in names.items():
        value = getattr(args, dest, None)
        if (
            isinstance(value, str)
            and value
            and (value == str(filename) or Path(value).expanduser().absolute() == Path(filename).absolute())
        ):
            return word
    return None


def exit_code(exc: BaseException, args: Any = None) -> int:
    """The exit status of an error escaping a command (the rule of the module docstring)."""
    if isinstance(exc, KeyboardInterrupt):
        return 130
    if isinstance(exc, USAGE_ERRORS) and not isinstance(exc, DATA_ERRORS):
        return 2
    names = {**_EVERY, **CLI_NAMES.get(getattr(args, "command", None) or "", {})}
    if isinstance(exc, OSError) and exc.errno in _PATH_ERRNOS and _named_path(exc, args, names):
        return 2
    return 1


def interrupted_message(args: Any = None) -> str:
    """The one line of a command stopped by Ctrl-C; for ``hevr encrypt`` with a store begun at
    ``--out``, how to finish it."""
    out = getattr(args, "out", None)
    if getattr(args, "command", None) != "encrypt" or not out:
        return "interrupted"
    local = "://" not in str(out)
    if local and not os.path.lexists(os.path.expanduser(str(out))):
        return "interrupted before the store was created; nothing was written"
    return (
        f"interrupted: {out} is not finished; the bricks written are kept: run the same hevr encrypt "
        "command with --resume to encrypt the rest"
    )


def cli_phrases(text: str, command: str = "") -> str:
    """``text`` with the Python phrases of :data:`CLI_PHRASES` in the command's words.

    >>> cli_phrases("finish it with encrypt_volume(..., resume=True)")
    "finish it with 'hevr encrypt … --resume'"
    """
    for python, cli in {**CLI_PHRASES["*"], **CLI_PHRASES.get(command, {})}.items():
        text = text.replace(python, cli)
    return text


def cli_message(exc: BaseException, args: Any = None) -> str:
    """The one-line message of an error escaping a command, in the command's words: a leading
    Python parameter name (``vol: …``) becomes the option it came from (``INPUT: …``); a message
    about a file the command line names starts with that option."""
    command = getattr(args, "command", None) or ""
    names = {**_EVERY, **CLI_NAMES.get(command, {})}
    text = cli_phrases(_message(exc), command)
    for flag in ("overwrite", "resume"):
        if flag in names:
            text = text.replace(f"{flag}=True", names[flag])
    m = _LEADING.match(text)
    if m:
        words = [names.get(re.sub(r"\[\d+\]$", "", part)) for part in re.split(r", |/", m.group(1))]
        if all(words):
            return ", ".join(dict.fromkeys(w for w in words if w)) + ": " + text[m.end() :]
    subjects = CLI_SUBJECTS.get(command, {})
    known = set(names.values()) | set(subjects.values())
    if text.startswith("--") or re.split(r"[: ]", text, maxsplit=1)[0] in known:
        return text
    subject = _named_path(exc, args, names) or next((subjects[c] for c in type(exc).__mro__ if c in subjects), None)
    return f"{subject}: {text}" if subject else text
