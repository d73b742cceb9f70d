"""Stress: concurrent creators of one new store, over many rounds (issue 24, item 2).

    python benchmarks/stress_exclusive.py --dir DIR [--rounds 100] [--procs 4] [--bits 256]

``--procs`` worker processes (spawned once) meet at a barrier each round and all call
``hevr.encrypt_volume`` into the same new local path at once, each with its own volume (every
voxel = its worker number). A round passes when exactly one call returned, every other call
raised ``StoreExistsError``, the store at the path passes ``verify="full"`` and decrypts to the
winner's volume everywhere, and nothing is left beside it. Prints one line per failure and a
summary; appends a section to benchmarks/history.md. This is a correctness stress, not a timing
benchmark (the rounds per second only say how hard it pushed).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from _machine import append, machine  # noqa: E402

SHAPE, BRICK = (4, 6, 5), 2  # 2 x 3 x 3 bricks


def _worker(rank: int, key_path: str, folder: str, rounds: int, barrier, results) -> None:
    warnings.simplefilter("ignore")
    import hevr

    key = hevr.load_key(key_path).public_key
    vol = np.full(SHAPE, rank + 1, np.uint8)
    for r in range(rounds):
        barrier.wait()
        try:
            ev = hevr.encrypt_volume(vol, f"{folder}/v{r}.zarr", key, brick=BRICK, progress=False, client=None)
            results.put((r, rank, "won", ev.meta.store_id))
        except hevr.StoreExistsError:
            results.put((r, rank, "lost", ""))
        except Exception as exc:  # noqa: BLE001 - reported as a failure of the round
            results.put((r, rank, "error", f"{type(exc).__name__}: {exc}"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", required=True, type=Path)
    ap.add_argument("--rounds", type=int, default=100)
    ap.add_argument("--procs", type=int, default=4)
    ap.add_argument("--bits", type=int, default=256)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import hevr

    args.dir.mkdir(parents=True, exist_ok=False)
    pub, priv = hevr.generate_keypair(args.bits)
    priv.save(args.dir / "key.json")
    stores = args.dir / "stores"
    stores.mkdir()
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(args.procs), ctx.Queue()
    procs = [
        ctx.Process(target=_worker, args=(i, str(args.dir / "key.json"), str(stores), args.rounds, barrier, results))
        for i in range(args.procs)
    ]
    t0 = time.perf_counter()
    for p in procs:
        p.start()
    got: dict[int, list] = {}
    for _ in range(args.rounds * args.procs):
        r, rank, what, detail = results.get(timeout=600)
        got.setdefault(r, []).append((rank, what, detail))
    for p in procs:
        p.join()
    wall = time.perf_counter() - t0
    failures = []
    for r in range(args.rounds):
        won = [(rank, d) for rank, what, d in got[r] if what == "won"]
        bad = [(rank, what, d) for rank, what, d in got[r] if what not in ("won", "lost")]
        path = stores / f"v{r}.zarr"
        if len(won) != 1 or bad:
            failures.append(f"round {r}: {len(won)} winners, errors {bad}")
            continue
        ev = hevr.open_volume(path, verify="full")
        values = {int(v) for idx in np.ndindex(*ev.grid) for v in priv.decrypt_array(ev.read_brick(idx))}
        if values != {won[0][0] + 1} or ev.meta.store_id != won[0][1]:
            failures.append(f"round {r}: the store holds {sorted(values)}, winner {won[0][0] + 1}")
    left = sorted(p.name for p in stores.iterdir() if p.name.startswith("."))
    if left:
        failures.append(f"left beside the stores: {left[:5]} ({len(left)} in all)")
    for f in failures:
        print("FAIL", f)
    summary = (
        f"{args.rounds} rounds × {args.procs} processes, {args.bits}-bit key, {SHAPE} voxels in "
        f"{int(np.prod([-(-s // BRICK) for s in SHAPE]))} bricks: {len(failures)} failures, "
        f"{wall:.1f} s ({args.rounds / wall:.1f} rounds/s)"
    )
    print(summary)
    append(f"## stress_exclusive.py — concurrent creators of one store\n\n{machine()}\n\n{summary}\n")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
