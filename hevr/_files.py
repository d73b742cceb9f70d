"""Small file helpers: atomic writes with a fixed mode (key files), and the one way hevr
reports a missing file or folder (keys, stores, images, volumes, output folders).

>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> write_atomic(os.path.join(d, "a.json"), "{}\\n", mode=0o600)
>>> oct(os.stat(os.path.join(d, "a.json")).st_mode & 0o777)
'0o600'
>>> require_file(os.path.join(d, "missing.json"), "key", "a key file")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
hevr.errors.MissingFileError: key: expected a key file, found nothing at .../missing.json
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import Any, Iterable

from .errors import ExistingFileError, MissingFileError

__all__ = ["require_file", "write_atomic", "write_checksummed"]


def write_atomic(path: str | os.PathLike, text: str, mode: int = 0o644, *, overwrite: bool = True,
                 name: str = "path") -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and
    ``os.replace``: the file never exists half-written, nor with a mode other than ``mode``.

    With ``overwrite=False`` an existing ``path`` is never replaced: the temporary file is
    hard-linked into place, which fails atomically if ``path`` exists (no window between a
    check and the write); :class:`hevr.ExistingFileError` names ``name`` then."""
    path = Path(path)
    directory = require_file(path.parent if str(path.parent) else Path("."), "path", "an existing folder",
                             directory=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}-", dir=directory)
    try:
        try:
            os.fchmod(fd, mode)
            fh = os.fdopen(fd, "w")
        except BaseException:
            os.close(fd)
            raise
        with fh:
            fh.write(text)
        if overwrite:
            os.replace(tmp, path)
        else:
            _link_new(tmp, path, name)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _link_new(tmp: str, path: Path, name: str) -> None:
    """Put ``tmp`` at ``path`` only if nothing is there, atomically; then drop ``tmp``."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise ExistingFileError(name, path) from None
    except OSError:  # a filesystem without hard links: exclusive create, then copy
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, os.stat(tmp).st_mode & 0o777)
        except FileExistsError:
            raise ExistingFileError(name, path) from None
        with os.fdopen(fd, "w") as out, open(tmp) as src:
            out.write(src.read())
    os.unlink(tmp)


def require_file(path: str | os.PathLike, name: str, expected: str, *, directory: bool = False) -> Path:
    """Return ``Path(path)`` if it exists (as a folder when ``directory``), else raise
    :class:`hevr.MissingFileError` naming the parameter ``name`` and what was ``expected``."""
    p = Path(path)
    try:
        found = p.is_dir() if directory else p.exists()
    except (OSError, ValueError):  # a name the OS refuses (too long, NUL byte) names nothing
        found = False
    if not found:
        raise MissingFileError(name, expected, p)
    return p


def write_checksummed(path: str | os.PathLike, parts: Iterable[Any]) -> None:
    """Write ``parts`` (bytes-like) and then the SHA-256 of all of them to ``path``, atomically:
    through ``<path>.tmp`` renamed over ``path`` — the layout of ``.hevr`` images and ``.hevrsums``
    files, whose readers check the trailer before anything else."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    digest = hashlib.sha256()
    try:
        with open(tmp, "wb") as fh:
            for part in parts:
                digest.update(part)
                fh.write(part)
            fh.write(digest.digest())
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
