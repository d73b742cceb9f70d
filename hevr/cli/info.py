"""``hevr info PATH``: where the command starts, light enough that a key file is described in
about a tenth of a second.

Describing a store, frame, sums file or scan needs Zarr, Dask or the readers
(:mod:`hevr.cli.describe`, half a second of imports); a key file needs the key code only. So a
local key file is recognised here, by the same tests and in the same order as
:func:`hevr.cli.describe.describe` applies them: a regular file, not named ``.hevr`` or
``.hevrsums``, not starting with a frame's or a sums file's signature (:mod:`hevr.core.magic`),
whose text is a JSON object that is an hevr or a python-paillier key. It is described by
:func:`hevr.cli.keys.info_key`. Every other PATH, and anything unusual on the way (a URL, a
folder, a FIFO, an unreadable file), goes to :func:`~hevr.cli.describe.describe`, imported then
(:func:`hevr.core.lazy.resolve`), which decides and reports exactly as before.
"""

from __future__ import annotations

import json
import stat
from pathlib import Path
from typing import Any

from ..core.lazy import resolve
from ..core.magic import IMAGE_MAGIC_PREFIX, SUMS_MAGIC_PREFIX
from ..crypto.phe_keys import is_phe_dict
from .keys import info_key

__all__ = ["DESCRIBE", "cmd_info", "key_file"]

#: Everything but a local key file: ``"module:function"`` relative to :mod:`hevr.cli`.
DESCRIBE = ".describe:describe"
# Bytes read to tell the kinds apart: a frame's signature and its version byte, a sums file's signature.
_HEAD = len(IMAGE_MAGIC_PREFIX) + 1


def key_file(text: str) -> tuple[Path, str] | None:
    """``(path, format)`` when ``text`` names a local key file, else None (module docstring).

    ``format`` is the name ``hevr info`` prints: ``"hevr"`` or ``"python-paillier (pheutil)"``.
    """
    if "://" in text:
        return None
    path = Path(text).expanduser()
    try:
        if not stat.S_ISREG(path.stat().st_mode) or path.suffix in (".hevr", ".hevrsums"):
            return None
        with open(path, "rb") as fh:
            head = fh.read(_HEAD)
        if head[:-1] == IMAGE_MAGIC_PREFIX or head == SUMS_MAGIC_PREFIX or head.lstrip()[:1] != b"{":
            return None
        doc = json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(doc, dict):
        return None
    if is_phe_dict(doc):
        return path, "python-paillier (pheutil)"
    return (path, "hevr") if doc.get("format") == "hevr-key" else None


def cmd_info(args: Any) -> int:
    """Print what PATH holds; 1 if a check failed (:mod:`hevr.cli.describe`)."""
    found = key_file(str(args.path))
    if found is not None:
        return info_key(*found)
    return resolve(DESCRIBE, __package__)(args)
