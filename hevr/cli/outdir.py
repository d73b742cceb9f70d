"""An output folder a command fills with many files (``hevr demo``), and what it may replace.

A command that writes a fixed set of names into ``--out DIR`` (``demo-key.json``, ``volume.zarr``,
frames, PNGs, ``summary.json`` …) must be runnable twice into the same folder, yet never
silently replace a file it did not write there (a user's key, notes, another tool's output).
So the folder records what the command wrote: the hidden file :data:`MARK` lists each name
with a fingerprint of what was written (a file's SHA-256; a store's ``store_id``), updated
after every write. A later run may replace a name only if it is listed and still holds what
the command wrote; any other file at one of its names is refused before anything is done
(:class:`hevr.ExistingFileError` naming the option, exit 2) unless ``--force``. Files with
other names in the folder are never touched. Private keys keep mode 0600 (they are written by
:meth:`hevr.PrivateKey.save`).

Each write itself is atomic and exclusive where nothing may be replaced
(:func:`hevr.core.files.write_file`); a name the command owns is replaced by a rename.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from pathlib import Path

from ..core.files import fs_errors, read_regular, write_atomic
from ..errors import ExistingFileError, HevrError
from .util import check_writable_folder

__all__ = ["MARK", "OutputFolder"]

#: The record of what a command wrote into its output folder (JSON: {"command", "files": {name: fingerprint}}).
MARK = ".hevr-outputs.json"


def fingerprint(path: Path) -> str | None:
    """What identifies the content of ``path``: ``sha256:…`` of a file, ``store:<store_id>`` of
    an hevr store folder, None for anything else (never owned)."""
    try:
        if path.is_symlink():
            return None
        if path.is_file():
            h = hashlib.sha256()
            with open(path, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
            return "sha256:" + h.hexdigest()
        if path.is_dir():
            doc = json.loads(read_regular(path / "zarr.json", "--out", "a store document", limit=1 << 24))
            sid = doc["attributes"]["hevr"]["store_id"]
            return f"store:{sid}" if isinstance(sid, str) and sid else None
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return None


class OutputFolder:
    """The folder ``path`` (created if missing) that ``command`` writes the names ``names`` into.

    Parameters
    ----------
    path : Path
    command : str
        Recorded in :data:`MARK`; a folder recorded by another command owns nothing for this one.
    names : iterable of str
        Every name the run will write (checked up front by :meth:`check`).
    force : bool
        Replace any file at those names (``--force``).
    option : str
        The option that named the folder, for messages.
    """

    def __init__(
        self, path: Path, command: str, names: Iterable[str], *, force: bool = False, option: str = "--out"
    ) -> None:
        self.path, self.command, self.names = Path(path), command, list(names)
        self.force, self.option = bool(force), option
        if not self.path.is_dir():  # the nearest existing folder above must take it (read-only: fails the run)
            above = next((p for p in self.path.parents if p.is_dir()), None)
            if above is not None:
                check_writable_folder(above, option)
            with fs_errors(f"{option}: creating the folder", self.path):
                self.path.mkdir(parents=True, exist_ok=True)
        check_writable_folder(self.path, option)  # before any work, not at the first file written
        self.files, self.foreign_mark = self._read_mark()

    def _read_mark(self) -> tuple[dict[str, str], bool]:
        """The names an earlier run of this command recorded, and whether a :data:`MARK` is
        there that is not such a record (then it is not this command's to replace)."""
        mark = self.path / MARK
        if not (mark.exists() or mark.is_symlink()):
            return {}, False
        try:  # read_regular: a FIFO there is no record (and would block)
            doc = json.loads(read_regular(mark, self.option, "a record of outputs", limit=1 << 24))
        except (OSError, ValueError, HevrError):
            return {}, True
        files = doc.get("files") if isinstance(doc, dict) and doc.get("command") == self.command else None
        if not isinstance(files, dict):
            return {}, True
        return {k: v for k, v in files.items() if isinstance(k, str) and isinstance(v, str)}, False

    def owns(self, name: str) -> bool:
        """Whether ``name`` holds what this command wrote there (so a run may replace it)."""
        recorded = self.files.get(name)
        return recorded is not None and fingerprint(self.path / name) == recorded

    def check(self) -> None:
        """Refuse (before any work) a file at one of the names that this command did not write."""
        if self.force:
            return
        if self.foreign_mark:
            raise ExistingFileError(self.option, self.path / MARK)
        for name in self.names:
            p = self.path / name
            if (p.exists() or p.is_symlink()) and not self.owns(name):
                raise ExistingFileError(self.option, p)

    def overwrite(self, name: str) -> bool:
        """The ``overwrite=`` to write ``name`` with: True where something is there that this
        run may replace (its own earlier output, or anything with ``force``)."""
        p = self.path / name
        return (p.exists() or p.is_symlink()) and (self.force or self.owns(name))

    def wrote(self, name: str) -> None:
        """Record that ``name`` now holds this command's output."""
        found = fingerprint(self.path / name)
        if found is None:
            self.files.pop(name, None)
        else:
            self.files[name] = found
        text = json.dumps({"command": self.command, "files": dict(sorted(self.files.items()))}, indent=1) + "\n"
        write_atomic(self.path / MARK, text, overwrite=True, name=self.option, doing="recording the outputs in")
