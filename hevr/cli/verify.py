"""What ``hevr info STORE`` checks beyond opening the store: with ``--verify`` every brick read
back (:func:`hevr.store.verify.verify_bricks`: digests, ranges, coprimality; each damaged
brick named by channel and index), and, always, the temporaries an interrupted or killed
write left beside the store (``.NAME.hevr-tmp-…``, ``.NAME.hevr-new-…``, ``.NAME.hevr-old-…``),
named with their sizes in one warning line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.siblings import temporaries
from ..errors import StoreError
from ..store.paths import interrupted_swaps, is_local
from ..store.reader import open_volume
from ..store.verify import verify_bricks
from .cluster import dask_client
from .util import disk_usage, human_bytes, plural, show_progress, warn_line

__all__ = ["leftovers", "warn_leftovers", "verify_store"]


def leftovers(path: str | Path) -> list[tuple[Path, int]]:
    """The temporary siblings of the local store ``path`` that exist now, with their sizes in
    bytes (a folder: all its files); none for a URL."""
    if not is_local(str(path)):
        return []
    found = {Path(p) for p in interrupted_swaps(str(path))} | set(temporaries(path))
    out = []
    for p in sorted(found):
        try:
            out.append((p, disk_usage(p)))
        except OSError:  # removed while we looked
            continue
    return out


def warn_leftovers(path: str | Path) -> None:
    """One warning line naming the temporaries beside ``path`` and their sizes (nothing if none)."""
    found = leftovers(path)
    if not found:
        return
    listed = ", ".join(f"{p.name} ({human_bytes(size)})" for p, size in found)
    total = human_bytes(sum(size for _, size in found))
    warn_line(
        f"beside {path}: {listed}, {total} in all: left by a write to {Path(path).name} that was interrupted "
        "(or is still running); the next write to it removes them, or remove them by hand"
    )


def verify_store(path: str, so: dict | None, args: Any) -> tuple[str, list[str], bool]:
    """``hevr info STORE --verify``: read every brick back. Returns the table's ``verify`` row,
    one line per damaged brick of a channel, and whether the check failed."""
    try:
        ev = open_volume(path, verify="none", storage_options=so)
    except StoreError as exc:
        return f"FAILED: the bricks cannot be read ({exc})", [], True
    with dask_client(
        getattr(args, "scheduler", None), getattr(args, "workers", None), own=getattr(args, "own_cluster", False)
    ) as client:
        report = verify_bricks(ev, client=client, progress=show_progress(args))
    levels = f" at level 0 and {ev.levels} pyramid level{'s' if ev.levels > 1 else ''}" if ev.levels else ""
    if report.ok:
        return (
            (
                f"ok: verified {plural(report.bricks, 'brick')}{levels} (every ciphertext of every channel read: "
                "chunk crc32c, brick digests, 0 < c < n², coprime to n)"
            ),
            [],
            False,
        )
    lines = [f"damaged: {p}" for p in report.problems]
    return f"FAILED: {len(report.damaged)} of {report.bricks} bricks damaged (listed below)", lines, True
