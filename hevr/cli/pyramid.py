"""``hevr pyramid``: add the encrypted multi-resolution pyramid to a store (server side, no key).

Each level halves the volume per axis (2×2×2 means, :mod:`hevr.volume.pyramid`), computed on the
ciphertexts by one Dask task per brick (:func:`hevr.build_pyramid`); an interrupted run resumes.
``hevr render --level L`` then renders a coarse preview with the same camera.
"""

from __future__ import annotations

from typing import Any

from ..store.pyramid import build_pyramid
from .cluster import dask_client, describe_client
from .storage import open_store, size_of, storage_options
from .util import (
    Timer,
    human_bytes,
    plural,
    show_progress,
    xyz,
)

__all__ = ["cmd_pyramid", "level_rows"]


def level_rows(meta: Any) -> list[tuple[str, str]]:
    """``hevr info`` rows describing a store's pyramid levels (none without a pyramid)."""
    rows = []
    for lv in meta.levels:
        again = "hevr encrypt ... --resume" if lv.packing is not None else "hevr pyramid"
        state = "complete" if lv.complete else f"INCOMPLETE (run {again} again to finish it)"
        packed = (
            f", packed: {lv.packing.slots} voxels per ciphertext ({lv.packing.slot_bits}-bit slots)"
            if lv.packing is not None
            else ""
        )
        rows.append((f"level {lv.level}", f"{xyz(lv.shape)} voxels{packed}, {state}"))
    return rows


def cmd_pyramid(args: Any) -> int:
    so = storage_options(args)
    ev = open_store(args.store, "STORE", so)
    store = ev.path
    before = ev.levels
    print(
        f"store:   {args.store}, {xyz(ev.shape)} voxels, {plural(ev.meta.n_bricks, 'brick')}, "
        f"{before} pyramid level{'s' if before != 1 else ''} so far"
    )
    if before >= args.levels:
        print(f"nothing to do: level{'s' if args.levels > 1 else ''} 1..{args.levels} exist")
        return 0
    size = size_of(store, so)
    with dask_client(args.scheduler, args.workers, own=getattr(args, "own_cluster", False)) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = build_pyramid(ev, args.levels, client=client, progress=show_progress(args))
    for name, text in level_rows(ev.meta):
        print(f"{name}: {text}")
    print(
        f"built levels {before + 1}..{args.levels} in {t.seconds:.2f} s; the store grew by "
        f"{human_bytes(size_of(store, so) - size)}"
    )
    return 0
