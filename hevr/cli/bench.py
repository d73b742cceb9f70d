"""``hevr bench``: the paper's Tables 1-3, the limits, python-paillier and scaling (hevr.bench)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..backends import available_backends
from ..bench.gpu import run_gpu_bench
from ..bench.runner import rewrite_report, run_bench
from ..runtime.scheduler import own_cluster
from .util import UsageError, show_progress, warn_line


def cmd_bench(args: Any) -> int:
    out = Path(args.out) if args.out else (Path("benchmarks") if Path("benchmarks").is_dir() else Path("."))
    if args.gpu:
        kernels = [b for b in available_backends() if b != "cpu"]
        if args.gpu_backend not in kernels:
            raise UsageError(
                f"--gpu-backend: expected one of {', '.join(kernels)} (the backend to prove against cpu), "
                f"got {args.gpu_backend!r}"
            )
        if args.paper or args.resume or args.report_only or args.only:
            raise UsageError(
                "--gpu: expected alone or with --quick, --out, --work, --gpu-backend, got it with "
                "--paper/--resume/--report-only/--only"
            )
        md, ok = run_gpu_bench(
            out,
            backend=args.gpu_backend,
            quick=args.quick,
            work=Path(args.work) if args.work else None,
            log_line=lambda s: print(s, flush=True),
        )
        print(f"wrote {md}")
        return 0 if ok else 1
    setting = "quick" if args.quick else "paper" if args.paper else "default"
    only = tuple(k.strip() for k in args.only.split(",") if k.strip()) if args.only else None
    workers = 2 if args.workers is None else args.workers
    if args.paper and not args.resume and not args.report_only:
        warn_line(
            "the paper's setting takes about 1.5 hours on 2 cores (mostly encrypting ~60 million masked "
            "ciphertexts); "
            "results are saved after every cell: stop with Ctrl-C and continue with --resume"
        )
    if args.resume and args.force:
        raise UsageError("--resume, --force: expected one of them, got both (--force starts the setting afresh)")
    if args.report_only:
        md = rewrite_report(setting, out)
        print(f"wrote {md}")
        return 0
    if args.own_cluster:  # the benchmark decrypts with its key beside the --scheduler cluster
        if not args.scheduler:
            raise UsageError(
                "--own-cluster: expected --scheduler ADDRESS as well (a cluster this command starts is "
                "this process's own already)"
            )
        own_cluster(args.scheduler)
    md = run_bench(
        setting,
        out,
        resume=args.resume,
        only=only,
        workers=workers,
        scheduler=args.scheduler,
        work=args.work,
        progress=show_progress(args),
        overwrite=args.force,
        log_line=lambda s: print(s, flush=True),
    )
    print(f"wrote {md}")
    return 0
