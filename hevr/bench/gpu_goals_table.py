"""The goal table of issue 40's GPU proof: ``goals.md`` from the rows the steps wrote (``goals.jsonl``).

Each goal of :data:`GOALS` beside the figure measured for it and whether it was met, the ``cpu``
curve by workers, and the packed step's rows (:func:`hevr.bench.gpu_packed.table_lines`). The
steps themselves are :mod:`hevr.bench.gpu_goals`'s.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .gpu_common import read_rows
from .gpu_packed import table_lines

__all__ = ["GOALS", "table"]

# issue 40's goals; a frame's goal is its seconds, "efficiency" the cpu curve's at the largest cluster
GOALS = {
    "products_per_s kernels": 1.0e8,
    "encrypt scalar": 3.0,
    "frame xray nearest": 0.10,
    "frame xray trilinear": 0.30,
    "frame tf trilinear": 1.0,
    "efficiency nearest": 0.80,
}


def _fmt(v: Any, unit: str = "") -> str:
    return "—" if v is None else f"{v:.3g}{unit}"


def table(out: Path) -> str:
    """``goals.md``: the goal table (each goal, the figure measured, met or not) and the cpu curve."""
    rows = read_rows(out)

    def first(**kw: Any) -> dict[str, Any] | None:
        return next((r for r in rows if all(r.get(k) == v for k, v in kw.items())), None)

    mach = first(step="machine")
    lines = ["# Issue 40's goals, measured", ""]
    if mach:
        lines += [
            f"Device: {mach.get('device')}; machine: {mach['machine'].get('cpu')}, {mach['machine'].get('cores')} "
            f"cores, {mach['machine'].get('date')}, commit {mach['machine'].get('commit')}.",
            "",
        ]
    lines += ["| goal | target | measured | met |", "|---|---:|---:|---|"]

    def goal(name: str, target: str, value: float | None, met: bool | None, note: str = "") -> None:
        lines.append(
            f"| {name} | {target} | {_fmt(value)}{note} | {'—' if met is None else ('yes' if met else 'no')} |"
        )

    p = first(step="throughput", what="products")
    k = p.get("kernels_per_s") if p else None
    goal("4096-bit products/s, kernels only", "≥ 1e8", k, None if not k else k >= GOALS["products_per_s kernels"])
    goal("4096-bit products/s, end to end", "—", p["end_to_end_per_s"] if p else None, None)
    q = first(step="throughput", what="pairs")
    goal(
        "pairs/s (10-bit), end to end / kernels",
        "—",
        q["end_to_end_per_s"] if q else None,
        None,
        f" / {_fmt(q.get('kernels_per_s') if q else None)}",
    )
    e = first(step="stores", what="encrypt scalar")
    goal(
        f"{e['size'] if e else 100}³ owner encryption, s" + (f" ({e['how']})" if e else ""),
        "≤ 3",
        e["seconds"] if e else None,
        None if not e else e["seconds"] <= GOALS["encrypt scalar"],
    )
    curve = [r for r in rows if r["step"] == "curve"]
    top = max((r["workers"] for r in curve), default=None)
    for what, target in (
        ("frame xray nearest", "≤ 0.10"),
        ("frame xray trilinear", "≤ 0.30"),
        ("frame tf trilinear", "≤ 1 (end to end)"),
    ):
        f = first(step="frames", what=what)
        c = first(step="curve", what=what, workers=top) if top else None
        same = (
            "" if not (f and c) else ("; identical to cpu" if f["sha256"] == c["sha256"] else "; NOT identical to cpu")
        )
        note = (
            ""
            if not f
            else f" ({f['backend']}, {f['size']}³, {f['image']}²{same}{'' if f['within_bound'] else '; OUT OF BOUND'})"
        )
        goal(
            what.replace("frame ", "frame: "),
            target,
            f["seconds"] if f else None,
            None if not f else f["seconds"] <= GOALS[what],
            note,
        )
    t1 = first(step="curve", what="frame xray nearest", workers=1)
    tn = first(step="curve", what="frame xray nearest", workers=top) if top else None
    eff = t1["seconds"] / (top * tn["seconds"]) if t1 and tn and top else None
    goal(
        f"cpu nearest, efficiency at {top} workers",
        "≥ 0.80",
        eff,
        None if eff is None else eff >= GOALS["efficiency nearest"],
    )
    if curve:
        lines += [
            "",
            "`cpu` resident frames (median s) by workers:",
            "",
            "| workers | frame | s | efficiency |",
            "|---:|---|---:|---:|",
        ]
        for r in curve:
            eff = t1["seconds"] / (r["workers"] * r["seconds"]) if t1 and r["what"] == "frame xray nearest" else None
            lines.append(f"| {r['workers']} | {r['what'][6:]} | {r['seconds']:.3g} | {_fmt(eff)} |")
    lines += table_lines(rows)
    text = "\n".join(lines) + "\n"
    (out / "goals.md").write_text(text, encoding="utf-8")
    return text
