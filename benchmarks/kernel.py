"""Kernel micro-benchmark: python benchmarks/kernel.py [--bits B] [--quick] [--no-append].

The workloads and the measurement live in hevr/bench/kernel_micro.py (``hevr bench`` runs
them too and puts the ratios beside the render benchmarks in RESULTS.md); run alone, this
script prints the table and appends it to benchmarks/history.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hevr.bench.kernel_micro import kernel_micro, report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bits", type=int, default=2048, help="bits of n (n^2 has twice as many)")
    ap.add_argument("--quick", action="store_true", help="smaller workloads, fewer repeats")
    ap.add_argument("--no-append", action="store_true", help="do not append to history.md")
    args = ap.parse_args(argv)
    text = report(kernel_micro(args.bits, args.quick))
    print(text)
    if not args.no_append:
        out = Path(__file__).with_name("history.md")
        with out.open("a", encoding="utf-8") as fh:
            fh.write(text + "\n")
        print(f"appended to {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
