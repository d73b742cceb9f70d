"""``hevr bench``: the paper's Tables 1-3, the limits, python-paillier and scaling (hevr._bench)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .._bench.runner import rewrite_report, run_bench
from ..paper import PAPER_IMAGE, PAPER_SIZE
from .util import UsageError, show_progress, warn_line

BENCH_EPILOG = f"""\
examples:
  hevr bench --quick              # ~20 s: 12^3 voxels, 16x16 px, keys 64-256 bits (CI smoke test)
  hevr bench                      # ~1 min: 32^3, 48x48 px, keys 256-1024 bits
  hevr bench --paper              # the paper's tables: {PAPER_SIZE}^3, {PAPER_IMAGE}x{PAPER_IMAGE} px, keys 64-3072 bits: ~1.5 h on 2 cores
  hevr bench --paper --resume     # continue a stopped run (finished blocks are kept)
  hevr bench --only t1,micro      # some blocks only: micro, t1, t2, t3, naive, scaling, pipeline
  hevr bench --paper --report-only  # rewrite RESULTS.md and the plot from results-paper.json

writes, into --out (default: ./benchmarks if it exists, else .):
  RESULTS.md (--paper) or RESULTS-<setting>.md, results-<setting>.json, scaling-<setting>.png
  (an earlier run's files of the setting: continued with --resume, replaced with --force,
  else refused with exit 2)
"""


def cmd_bench(args: Any) -> int:

    setting = "quick" if args.quick else "paper" if args.paper else "default"
    out = Path(args.out) if args.out else (Path("benchmarks") if Path("benchmarks").is_dir() else Path("."))
    only = tuple(k.strip() for k in args.only.split(",") if k.strip()) if args.only else None
    workers = 2 if args.workers is None else args.workers
    if args.paper and not args.resume and not args.report_only:
        warn_line("the paper's setting takes about 1.5 hours on 2 cores (mostly encrypting ~60 million masked "
                  "ciphertexts); "
                  "results are saved after every cell: stop with Ctrl-C and continue with --resume")
    if args.resume and args.force:
        raise UsageError("--resume, --force: expected one of them, got both (--force starts the setting afresh)")
    if args.report_only:
        md = rewrite_report(setting, out)
        print(f"wrote {md}")
        return 0
    md = run_bench(setting, out, resume=args.resume, only=only, workers=workers, scheduler=args.scheduler,
                   work=args.work, progress=show_progress(args), overwrite=args.force,
                   log_line=lambda s: print(s, flush=True))
    print(f"wrote {md}")
    return 0
