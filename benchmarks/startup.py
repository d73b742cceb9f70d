"""Issue 29, item 8: what a ``hevr`` command costs before it does anything (start-up time).

Times, in fresh processes, the commands whose cost is almost all start-up: ``hevr --version``,
``hevr --help``, ``hevr render --help`` and ``hevr info KEY`` (a 1024-bit private key file made
here), beside the interpreter alone (``python -c pass``) and ``python -c "import hevr"``. The
cases run round-robin, RUNS rounds after one warm-up round (so that a burst of load on the machine
hits every case alike); the median, minimum and maximum wall-clock times are kept, and the
heavy modules (zarr, dask, distributed, numpy, ...) each command leaves imported.

Usage::

    python benchmarks/startup.py [--runs 20] [--label after] [--out benchmarks/results-startup.json]

``hevr`` is the console script beside this interpreter (what a user runs). To time another
checkout with the same interpreter, put it first on the path: ``PYTHONPATH=/path/to/checkout
python benchmarks/startup.py --label before`` (the installed package is an editable one, which
the path overrides). The results file keeps one entry per label (a run replaces its label's).
Goals (issue 29): ``--version`` and ``--help`` at most 0.3 s, ``info KEY`` at most 0.5 s.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hevr.bench.measure import machine

HERE = Path(__file__).resolve().parent
HEAVY = ("zarr", "dask", "distributed", "fsspec", "numcodecs", "numpy", "PIL", "gmpy2")
GOALS = {"--version": 0.3, "--help": 0.3, "render --help": 0.3, "info KEY": 0.5}

# Run a command as the console script does, then print the heavy modules it left imported.
PROBE = (
    "import sys\nfrom hevr.cli.main import main\nsys.argv[0] = 'hevr'\ntry:\n    main(sys.argv[1:])\n"
    "finally:\n    print('MODULES', ','.join(m for m in " + repr(HEAVY) + " if m in sys.modules), file=sys.stderr)\n"
)


def hevr_script() -> list[str]:
    """The ``hevr`` console script beside this interpreter, else ``python -m hevr``."""
    script = Path(sys.executable).with_name("hevr")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "hevr"]


def cases(key: Path) -> dict[str, list[str]]:
    hevr = hevr_script()
    return {
        "python -c pass": [sys.executable, "-c", "pass"],
        "import hevr": [sys.executable, "-c", "import hevr"],
        "--version": hevr + ["--version"],
        "--help": hevr + ["--help"],
        "render --help": hevr + ["render", "--help"],
        "info KEY": hevr + ["info", str(key)],
    }


def once(argv: list[str], cwd: Path) -> float:
    t = time.perf_counter()
    subprocess.run(argv, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t


def heavy_modules(argv: list[str], cwd: Path) -> list[str] | None:
    """The heavy modules a ``hevr`` command leaves imported (None for the other cases)."""
    hevr = hevr_script()
    if argv[: len(hevr)] != hevr:
        return None
    out = subprocess.run(
        [sys.executable, "-c", PROBE, *argv[len(hevr) :]], cwd=cwd, capture_output=True, text=True, check=False
    )
    line = next((x for x in out.stderr.splitlines() if x.startswith("MODULES")), "MODULES ")
    return [m for m in line.partition(" ")[2].split(",") if m]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="timed rounds (default 20)")
    ap.add_argument("--label", default="current", help="this run's name in the results file")
    ap.add_argument("--out", type=Path, default=HERE / "results-startup.json", help="results file (JSON)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        subprocess.run(
            hevr_script() + ["keygen", "--bits", "1024", "--out", "key.json"],
            cwd=work,
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        todo = cases(work / "key.json")
        times: dict[str, list[float]] = {name: [] for name in todo}
        for rnd in range(args.runs + 1):  # round 0 warms the file cache and is not kept
            for name, argv in todo.items():
                t = once(argv, work)
                if rnd:
                    times[name].append(t)
        modules = {name: heavy_modules(argv, work) for name, argv in todo.items()}
    rows = []
    for name, ts in times.items():
        med = statistics.median(ts)
        rows.append(
            {
                "case": name,
                "median_s": round(med, 4),
                "min_s": round(min(ts), 4),
                "max_s": round(max(ts), 4),
                "goal_s": GOALS.get(name),
                "meets_goal": None if name not in GOALS else med <= GOALS[name],
                "heavy_modules": modules[name],
                "times_s": [round(t, 4) for t in ts],
            }
        )
    how = "the hevr console script" if len(hevr_script()) == 1 else "python -m hevr"
    run = {
        "label": args.label,
        "machine": machine(),
        "runs": args.runs,
        "hevr": how,
        "load_average_end": os.getloadavg()[0],
        "cases": rows,
    }
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {"runs": []}
    doc["runs"] = [r for r in doc["runs"] if r["label"] != args.label] + [run]
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{args.label}: {args.runs} runs, medians (min .. max), heavy modules left imported")
    for r in rows:
        goal = f"  goal <= {r['goal_s']} s: {'ok' if r['meets_goal'] else 'MISSED'}" if r["goal_s"] else ""
        mods = f"  [{', '.join(r['heavy_modules']) or '-'}]" if r["heavy_modules"] is not None else ""
        print(f"  {r['case']:<15} {r['median_s']:.3f} s ({r['min_s']:.3f} .. {r['max_s']:.3f}){goal}{mods}")


if __name__ == "__main__":
    main()
