"""What the key holder's known-stores record costs with many entries (issue 47: "a look-up stays
fast with 50 000 entries").

    python benchmarks/known_stores.py [--entries 50000] [--rounds 5]

Writes a record of N signed entries (plus one real verifiable store) in a temporary folder, then
times, per round: the first look-up in a process (parse: the cache dropped), a look-up from the
cache, the first MAC check of all the key's entries (``accepted_untagged``: what a decryption under
the key's policy runs), a later one, ``retired_by`` (every file frame's decryption), a
``record_verified`` of a store already recorded (a no-op) and a ``trust_store`` (rewrites the
file). Medians over the rounds; the file's size. Appends a section to benchmarks/history.md and
writes benchmarks/results-known-stores.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import dask  # noqa: E402
import numpy as np  # noqa: E402
from _machine import append, machine  # noqa: E402

import hevr  # noqa: E402
from hevr.store import known, known_file  # noqa: E402
from hevr.store.known_file import KnownStore, document, signed_by  # noqa: E402


def _timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--entries", type=int, default=50_000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "hevr"
        folder.mkdir(mode=0o700)
        path = folder / "known_stores.json"
        os.environ["HEVR_KNOWN_STORES"] = str(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
            _, priv = hevr.generate_keypair(512)
        with dask.config.set(scheduler="sync"):
            ev = hevr.encrypt_volume(
                np.zeros((8, 8, 8), np.uint8), Path(tmp) / "v.zarr", priv, brick=4, progress=False
            )  # recorded (signed) at encryption
        mine = known.known_stores()
        fp = priv.public_key.fingerprint
        many = {
            f"/stores/{i}.zarr": signed_by(
                priv,
                f"/stores/{i}.zarr",
                KnownStore(
                    f"{i:016x}", "sha256:" + "0" * 64, True, fp, "2026-01-01T00:00:00Z", retired=(f"{i + 10**9:016x}",)
                ),
            )
            for i in range(args.entries)
        }
        path.write_text(document({**many, **{k: v for k, v in mine.items() if v.mac}}))
        os.chmod(path, 0o600)
        rows: dict[str, list[float]] = {
            k: []
            for k in (
                "first look-up (parse)",
                "look-up (cached)",
                "first MAC check of all entries",
                "MAC check (cached)",
                "retired_by",
                "record_verified (already recorded)",
                "trust_store (rewrites the file)",
            )
        }
        img = hevr.render(ev, hevr.Camera.orbit(ev, azimuth=20, width=6, height=6), progress=False)
        for _ in range(args.rounds):
            known_file._CACHE.clear()
            os.utime(path)  # a new mtime: the next read parses
            rows["first look-up (parse)"].append(_timed(lambda: known.check_known(ev)))
            rows["look-up (cached)"].append(_timed(lambda: known.check_known(ev)))
            rows["first MAC check of all entries"].append(_timed(lambda: known.accepted_untagged("0" * 16, priv)))
            rows["MAC check (cached)"].append(_timed(lambda: known.accepted_untagged("0" * 16, priv)))
            rows["retired_by"].append(_timed(lambda: known.retired_by(f"{123 + 10**9:016x}")))
            rows["record_verified (already recorded)"].append(
                _timed(lambda: known.record_verified(img.verification, priv))
            )
            rows["trust_store (rewrites the file)"].append(_timed(lambda: known.trust_store(ev, priv)))
        assert known.retired_by(f"{123 + 10**9:016x}") == ("/stores/123.zarr", f"{123:016x}")
        size = path.stat().st_size
    med = {k: statistics.median(v) for k, v in rows.items()}
    where = machine()
    result = {
        "machine": where,
        "entries": args.entries,
        "rounds": args.rounds,
        "file_bytes": size,
        "median_seconds": med,
    }
    out = Path(__file__).resolve().parent / "results-known-stores.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        f"## benchmarks/known_stores.py: {args.entries} entries ({size / 2**20:.1f} MiB), median of "
        f"{args.rounds} rounds",
        "",
        where,
        "",
        "| operation | median |",
        "|---|---|",
    ]
    for k, v in med.items():
        lines.append(f"| {k} | {v * 1e3:.3f} ms |" if v < 1 else f"| {k} | {v:.2f} s |")
    text = "\n".join(lines)
    append(text)
    print(text)


if __name__ == "__main__":
    main()
