"""Paillier primitives: hevr vs python-paillier (phe) vs a bare gmpy2 modular multiplication.

Run: python benchmarks/crypto.py [--bits 1024 2048 3072] [--n 200]
Prints a table and appends it to benchmarks/history.md (``hevr bench`` runs the same
measurements and writes benchmarks/RESULTS.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _machine import append, machine  # noqa: E402

from hevr.bench.crypto_micro import crypto_micro  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bits", type=int, nargs="+", default=[1024, 2048, 3072])
    ap.add_argument("--n", type=int, default=200, help="operations per measurement")
    args = ap.parse_args(argv)
    lines = [
        f"## crypto.py — Paillier primitives\n\nMachine: {machine()}\n",
        "| bits | operation | hevr µs | phe µs | phe / hevr | bare a·b mod n² µs | hevr / bare |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for bits in args.bits:
        res = crypto_micro(bits, args.n)
        table_s = res["table_s"]
        for r in res["rows"]:
            name, h, p, bare = r["name"], r["hevr_s"], r["phe_s"], r["bare_s"]
            lines.append(
                f"| {bits} | {name} | {h * 1e6:,.1f} | {p * 1e6:,.1f} | {p / h:,.2f}× | {bare * 1e6:,.2f} | "
                f"{h / bare:,.2f} |"
            )
        lines.append(f"| {bits} | owner tables (once per key and process) | {table_s * 1e6:,.0f} | | | | |")
        print("\n".join(lines[-7:]), flush=True)
    lines.append(
        "\nphe columns: `raw_encrypt` (random r, r^n mod n² with gmpy2), `raw_decrypt` (CRT), "
        "`_raw_add`, `_raw_mul`. Goals at 2048 bits: owner encrypt ≥ 20× phe; decrypt no slower "
        "than phe; ⊕ within 1.2× of the bare multiplication."
    )
    text = "\n".join(lines)
    print(text)
    append(text)


if __name__ == "__main__":
    main()
