"""Encrypting the paper's 100³ phantom on a 2-worker LocalCluster, beside Tables 1–3.

Run: python benchmarks/encrypt.py [--size 100] [--bits 2048] [--workers 2] [--brick 25] [--quick]
Appends a section to benchmarks/history.md. The brick divides the volume so the store
holds exactly the ciphertext bytes (Zarr pads edge chunks to the full brick shape).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _machine import append, machine  # noqa: E402

import hevr  # noqa: E402

PAPER_ENCRYPT = {
    2048: {"scalar": 16880.0, 4: 62959.05},
    1024: {"scalar": 2256.01, 4: 8512.23},
    512: {"scalar": 327.24, 4: 1199.68},
}
PAPER_STORAGE_MB = {"scalar": 512, 4: 2048}  # Table 2 at 2048 bits, 100³ voxels


def store_bytes(path: Path, channel: str) -> int:
    return sum(f.stat().st_size for f in (path / channel / "c").rglob("*") if f.is_file())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=100)
    ap.add_argument("--bits", type=int, default=2048)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--brick", type=int, default=25)
    ap.add_argument("--quick", action="store_true", help="size 40, 1024 bits")
    ap.add_argument("--only", choices=["scalar", "vector"], default=None, help="measure one channel only")
    ap.add_argument(
        "--keep",
        type=Path,
        default=None,
        help="keep the stores and the private key in this folder (for benchmarks/render.py)",
    )
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.bits, args.brick = 40, 1024, 20
    from distributed import Client, LocalCluster

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pub, priv = hevr.generate_keypair(args.bits)
    vol = hevr.phantom(args.size)
    tmp = args.keep or Path(tempfile.mkdtemp(prefix="hevr-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    priv.save(tmp / "key.json", overwrite=True)  # the scratch folder of this run (--keep reuses it)
    rows = []
    with (
        LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cl,
        Client(cl) as client,
    ):
        cases = [("scalar", {"scalar": True}), (4, {"scalar": False, "vector_dims": 4})]
        if args.only:
            cases = cases[:1] if args.only == "scalar" else cases[1:]
        for label, kw in cases:
            path = tmp / f"{label}.zarr"
            t = time.perf_counter()
            hevr.encrypt_volume(vol, path, priv, brick=args.brick, client=client, progress=False, overwrite=True, **kw)
            secs = time.perf_counter() - t
            channel = "scalar" if label == "scalar" else "vector"
            nbytes = store_bytes(path, channel)
            # the paper's numbers are for 100³ voxels only
            paper = PAPER_ENCRYPT.get(args.bits, {}).get(label) if args.size == 100 else None
            rows.append((label, secs, paper, nbytes))
            print(f"{label}: {secs:.1f} s, {nbytes / 1e6:.1f} MB", flush=True)
    lines = [
        f"## encrypt.py — encrypting the {args.size}³ phantom, {args.bits}-bit key, "
        f"{args.workers}-worker LocalCluster, brick {args.brick}, owner-side path\n",
        f"Machine: {machine()}\n",
        "| channel | hevr s | paper s (Table 1/3) | speed-up | per voxel·component µs·core | ciphertext bytes "
        "| paper Table 2 |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for label, secs, paper, nbytes in rows:
        k = 1 if label == "scalar" else 4
        per = secs * args.workers / (args.size**3 * k) * 1e6
        paper_s = f"{paper:,.0f}" if paper else "–"
        speed = f"{paper / secs:,.0f}×" if paper else "–"
        tbl2 = f"{PAPER_STORAGE_MB[label]} MB" if args.size == 100 and args.bits == 2048 else "–"
        name = "scalar" if label == "scalar" else "4-dim vector"
        lines.append(
            f"| {name} | {secs:,.1f} | {paper_s} | {speed} | {per:,.0f} | {nbytes:,} ({nbytes / 1e6:,.0f} MB) "
            f"| {tbl2} |"
        )
    lines.append(
        "\nPaper: single-threaded Java prototype, 2.9 GHz i7 (2016). Table 2 counts 100³·2048·2/8 "
        "bytes = 512·10⁶ B as 512 MB; the store holds exactly the ciphertext bytes plus a few "
        "kB of JSON metadata."
    )
    text = "\n".join(lines)
    print(text)
    append(text)


if __name__ == "__main__":
    main()
