"""Resume journals: owner-side evidence that ``resume=True`` continues the *same* volume.

``encrypt_volume(..., resume=True)`` must refuse another input volume of the same shape,
or the finished store would mix bricks of two volumes. The evidence cannot live in the
store: a hash of the plaintext there would let anyone who reads the store confirm a guessed
volume. So it stays with the data owner, in a **journal** in the owner's cache folder:

* folder: Dask config ``hevr.journal-dir`` (env ``DASK_HEVR__JOURNAL_DIR``), else
  ``hevr/journals`` in the user's cache folder (``$XDG_CACHE_HOME``, else ``.cache`` in the
  home folder), created mode 0700;
* file: ``<store_id>.json`` (mode 0600), written before the first brick is encrypted;
* content: the store's path, id and key fingerprint, and per brick
  SHA-256(dtype ‖ shape ‖ the brick's plaintext bytes, C order).

A resume recomputes the per-brick digests of the volume it is given and refuses any
difference, naming the first brick that differs. A journal lives as long as its store: it
stays after completion (so that ``resume=True`` on a finished store stays a verified no-op)
and is deleted when ``overwrite=True`` replaces the store; journals of stores deleted by
hand can be deleted with them (their names are the stores' ``store_id``). A resume on a machine without the
journal is refused too: the input cannot be shown to be the same. The journal holds
digests of the plaintext; it is as sensitive as a hash of the volume and stays on the
owner's machine, next to the plaintext it describes (docs/security.md).

>>> import numpy as np
>>> plain_digest(np.zeros((2, 2, 2), np.uint8)) == plain_digest(np.zeros((2, 2, 2), np.int8))
False
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import dask
import dask.array
import numpy as np

from ..core.files import fs_errors, read_regular, write_atomic
from ..errors import ParameterError
from ..runtime.scheduler import compute

log = logging.getLogger(__name__)

__all__ = [
    "journal_dir",
    "journal_path",
    "plain_digest",
    "input_digests",
    "write_journal",
    "check_journal",
    "remove_journal",
]

FORMAT = "hevr-resume-journal"


def journal_dir() -> Path:
    """The folder of resume journals (module docstring)."""
    configured = dask.config.get("hevr.journal-dir", None)
    if configured:
        return Path(configured).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "hevr" / "journals"


def journal_path(store_id: str) -> Path:
    return journal_dir() / f"{store_id}.json"


def plain_digest(block: np.ndarray) -> str:
    """SHA-256 hex of one plaintext brick: dtype, shape and bytes, in native byte order (a
    ``>i2`` brick and its ``<i2`` twin have one digest)."""
    arr = np.ascontiguousarray(block, dtype=np.dtype(block.dtype).newbyteorder("="))
    h = hashlib.sha256(f"{arr.dtype.str}|{arr.shape}|".encode())
    h.update(arr.data.cast("B") if arr.size else b"")
    return h.hexdigest()


def input_digests(
    vol: Any, brick: tuple[int, int, int], bricks: Sequence[tuple[int, int, int]], client: Any = None
) -> dict[tuple[int, int, int], str]:
    """Per-brick plaintext digests of ``vol``: in this process for in-memory arrays, one task
    per brick (read inside the task) for dask arrays."""
    if not isinstance(vol, dask.array.Array):
        return {idx: plain_digest(vol[tuple(slice(i * b, (i + 1) * b) for i, b in zip(idx, brick))]) for idx in bricks}
    blocks = vol.rechunk(brick).to_delayed()
    task = dask.delayed(plain_digest, pure=True)
    out = compute([task(blocks[idx]) for idx in bricks], client=client, progress=False, desc="digest")
    return dict(zip(bricks, out))


def write_journal(store_id: str, path: str, fingerprint: str, digests: dict) -> Path:
    """Record the input of a new store (before any brick is encrypted)."""
    folder = journal_dir()
    with fs_errors("creating the resume journal folder", folder):
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    doc = {
        "format": FORMAT,
        "version": 1,
        "store": path,
        "store_id": store_id,
        "fingerprint": fingerprint,
        "bricks": {",".join(map(str, k)): v for k, v in digests.items()},
    }
    target = journal_path(store_id)
    write_atomic(target, json.dumps(doc, indent=1) + "\n", mode=0o600)
    log.info("resume journal of %s: %s", path, target)
    return target


def remove_journal(store_id: str) -> None:
    """Forget the journal of a store that was replaced (``overwrite=True``); best effort."""
    if store_id:
        try:
            journal_path(store_id).unlink(missing_ok=True)
        except OSError as exc:  # pragma: no cover - a read-only cache folder
            log.warning("could not remove the resume journal of store %s: %s", store_id, exc)


def check_journal(store_id: str, path: str, fingerprint: str, digests: dict) -> None:
    """Refuse a resume whose input differs from the interrupted run's (or cannot be compared)."""
    target = journal_path(store_id)
    try:
        doc = json.loads(read_regular(target, "journal", "a resume journal", limit=1 << 26))
        recorded = doc["bricks"] if doc.get("format") == FORMAT and doc.get("store_id") == store_id else None
    except FileNotFoundError:
        raise ParameterError(
            f"resume: no resume journal for {path} at {target}; the run was started on another machine or "
            "the journal was deleted, so the input cannot be shown to be the same volume. Start over with "
            "overwrite=True (or point the Dask config key hevr.journal-dir at the journal's folder)"
        ) from None
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ParameterError(
            f"resume: the resume journal {target} cannot be read ({type(exc).__name__}); start over with overwrite=True"
        ) from None
    if recorded is None or doc.get("fingerprint") != fingerprint:
        raise ParameterError(f"resume: the resume journal {target} does not belong to the store {path}")
    for idx, digest in digests.items():
        if recorded.get(",".join(map(str, idx))) != digest:
            raise ParameterError(
                f"vol: brick {idx} differs from the volume the interrupted run of {path} encrypted; resume needs "
                "the same input volume (start over with overwrite=True to encrypt another one)"
            )
