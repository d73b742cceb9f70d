"""The goals of the earlier issues (2-5), judged from a benchmark run's cells at the goal key size.

Each goal is a measured figure and a threshold; :func:`goals` gives the verdicts as data (a test
checks them), :func:`goals_markdown` the report's table of them.
"""

from __future__ import annotations

from typing import Any

from . import paper
from .report_cells import DASH, lookup, number


def goals(doc: dict) -> list[tuple[str, str, str, float | None, bool | None]]:
    """(issue, goal, measured text, value, met) for the goals of issues 2-5 (at 2048 bits)."""
    c, b = doc["cells"], doc["setting"].get("goal_bits")
    if not b:
        return []
    out = []
    crypto = {r["name"]: r for r in (lookup(c, f"micro.crypto.{b}", "rows") or [])}

    def add(issue: str, goal: str, value: float | None, ok: Any, text: str) -> None:
        out.append(
            (
                issue,
                goal,
                text if value is not None else "not measured",
                value,
                None if value is None else bool(ok(value)),
            )
        )

    r = crypto.get("encrypt (owner, PrivateKey)")
    v = r and r["phe_s"] / r["hevr_s"]
    add("#2", "owner encryption ≥ 20× faster than phe", v, lambda x: x >= 20, f"{v:.1f}×" if v else "")
    r = crypto.get("decrypt")
    v = r and r["hevr_s"] / r["phe_s"]
    add("#2", "decryption no slower than phe (hevr ÷ phe ≤ 1)", v, lambda x: x <= 1.0, f"{v:.2f}" if v else "")
    r = crypto.get("⊕ add")
    v = r and r["hevr_s"] / r["bare_s"]
    add("#2", "⊕ within 1.2× of a bare `a*b % n2`", v, lambda x: x <= 1.2, f"{v:.2f}×" if v else "")
    for dims, key, ref in (
        (1, f"t1.{b}.obf.encrypt", paper.TABLE1["nearest"][True]["encrypt"].get(b)),
        (4, f"t3.{b}.4.encrypt", paper.TABLE3_ENCRYPT[4].get(b)),
    ):
        if ref is None:
            continue
        s = lookup(c, key, "seconds")
        v = s and ref / s
        add(
            "#3",
            f"{'scalar' if dims == 1 else '4-dim'} encryption ≥ 100× faster than the paper ({ref:,.0f} s)",
            v,
            lambda x: x >= 100,
            f"{number(s)} s = {v:.0f}×" if v else "",
        )
    work = {w["name"]: w for w in (lookup(c, f"micro.kernel.{b}", "workloads") or [])}
    for name, lim in (("nearest", 1.3), ("trilinear", 3.0)):
        v = work.get(name, {}).get("ratio")
        add(
            "#4",
            f"kernel {name}: time per pair ≤ {lim} × one `a*b % n2`",
            v,
            lambda x, lim=lim: x <= lim,
            f"{v:.2f}" if v else "",
        )
    for text, key, field, lim in (
        ("X-ray nearest render ≤ 6 s", f"t1.{b}.obf.nearest", "seconds", 6),
        ("X-ray trilinear render ≤ 40 s", f"t1.{b}.obf.trilinear", "seconds", 40),
        ("TF 4-dim, 4 colours, nearest ≤ 25 s", f"t3.{b}.4.4", "seconds", 25),
        ("TF 4-dim, 4 colours, trilinear ≤ 120 s", f"goal.tf4_trilinear.{b}", "seconds", 120),
        ("150² RGB image decrypted ≤ 6 s on one core", f"t3.{b}.4.4", "decrypt_s", 6),
        ("TF 4-dim, 4 colours, coloured on the client, end to end ≤ 25 s", f"client.{b}.tf4", "seconds", 25),
    ):
        v = lookup(c, key, field)
        add("#5", text, v, lambda x, lim=lim: x <= lim, f"{number(v)} s" if v is not None else "")
    one, two = (
        lookup(c, "scale.workers.1", "seconds"),
        lookup(c, f"t1.{doc['setting']['workers_bits']}.obf.trilinear", "seconds"),
    )
    v = one and two and one / two
    add(
        "#5",
        "2-worker speed-up ≥ 1.8× (trilinear X-ray)",
        v,
        lambda x: x >= 1.8,
        f"{number(one)} s → {number(two)} s = {v:.2f}×" if v else "",
    )
    return out


def goals_markdown(doc: dict) -> list[str]:
    g = goals(doc)
    if not g:
        return []
    lines = [
        f"## Goals of the earlier issues, judged in this run ({doc['setting']['goal_bits']}-bit key)",
        "",
        "| issue | goal | measured | verdict |",
        "|---|---|---|---|",
    ]
    for issue, goal, text, _v, ok in g:
        lines.append(f"| {issue} | {goal} | {text} | {DASH if ok is None else '**met**' if ok else '**not met**'} |")
    return lines + [""]
