"""The benchmark report: markdown and the scaling plot from a run's raw numbers (the JSON).

This module writes the report's head (machine, versions, setting), its scaling and pipeline sections
and puts the sections together; the others are :mod:`hevr.bench.report_goals` (the earlier issues'
goals), :mod:`hevr.bench.report_tables` (the paper's Tables 1-3) and :mod:`hevr.bench.report_limits`
(floors, primitives, python-paillier), all formatting cells through :mod:`hevr.bench.report_cells`.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any

from ..core.files import write_atomic
from . import paper
from .plot import plot_scaling
from .report_cells import lookup, number
from .report_goals import goals, goals_markdown
from .report_limits import limits, micro, naive
from .report_tables import table1, table2, table3
from .settings import BenchSettings, block_names

__all__ = ["goals", "markdown", "write_report"]


def _header(doc: dict) -> list[str]:
    m, s = doc["machine"], doc["setting"]
    # the 1-worker scaling cell is the exception: the run's own worker count is the largest
    nw = max((c["workers"] for c in doc["cells"].values() if isinstance(c, dict) and "workers" in c), default=2)
    v = m["versions"]
    order = ["python", "hevr", "gmpy2", "numpy", "dask", "distributed", "zarr", "phe"]
    keys = [k for k in order if k in v] + sorted(set(v) - set(order))  # JSON round trips sort keys
    vers = ", ".join(f"{k} {v[k]}" for k in keys if v[k])
    restarts = len(doc.get("machines", [])) - 1
    return [
        f"# hevr benchmarks — `hevr bench --{s['name']}`"
        if s["name"] != "default"
        else "# hevr benchmarks — `hevr bench`",
        "",
        f"- **Machine:** {m['cpu']}, {m['cores']} cores, {m['memory_gib']} GiB, {m['os']}; run started {m['date']}"
        + (f" (resumed {restarts}×)" if restarts > 0 else "")
        + ".",
        f"- **Versions:** {vers}" + (f"; hevr commit `{m['commit']}`." if m.get("commit") else "."),
        f"- **Setting:** {s['size']}³ phantom, {s['image']}² image, bricks of {s['brick']}³, camera "
        "`Camera.orbit(azimuth=30, elevation=20)`, step 1 voxel; "
        f"{nw} Dask worker process{'es' if nw != 1 else ''} × 1 thread. "
        "Renders are from scratch (`cache=False`), timed end to end as a user waits (graph, map, reduce, "
        "finishing, packing); decryption is the client, one core.",
        f"- **The paper's figures** ({paper.MACHINE}) are quoted beside ours in every cell as "
        "`ours / paper (paper ÷ ours×)`. They come from a 2016 laptop running single-threaded Java; ours "
        f"from {nw} worker processes on the machine above, so part of every ratio is hardware and parallelism, "
        "not algorithm; the paper's hardware was not measured here. The limit section below shows instead how "
        "close we are to this machine's own arithmetic floor."
        if s["paper_case"]
        else "- The paper's figures are for 100³ voxels at 150² pixels and are not shown for this setting.",
        f"- Raw numbers: `results-{s['name']}.json` (same folder); plot: `scaling-{s['name']}.png`.",
        "",
    ]


def _scaling(doc: dict) -> list[str]:
    c, s = doc["cells"], doc["setting"]
    lines = ["## Scaling", ""]
    one, two = lookup(c, "scale.workers.1"), lookup(c, f"t1.{s['workers_bits']}.obf.trilinear")
    if one and two:
        lines += [
            f"Workers (trilinear X-ray, {s['size']}³, {s['workers_bits']} bits): 1 worker {number(one['seconds'])} s, "
            f"{two['workers']} workers {number(two['seconds'])} s — speed-up "
            f"**{one['seconds'] / two['seconds']:.2f}×**.",
            "",
        ]
    rows = [
        (
            size,
            lookup(c, f"scale.size.{size}.encrypt"),
            lookup(c, f"scale.size.{size}.nearest"),
            lookup(c, f"scale.size.{size}.trilinear"),
        )
        for size in s["scaling_sizes"]
    ]
    rows = [r for r in rows if r[1] and r[2] and r[3]]
    if rows:
        base = rows[0]
        lines += [
            f"Volume size at {s['scaling_bits']} bits, {s['image']}² image (cost ∝ samples for renders, ∝ "
            "voxels for encryption):",
            "",
            "| volume | encrypt s | × | nearest samples | nearest s | × | trilinear pairs | trilinear s | × |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for size, e, n, t in rows:
            lines.append(
                f"| {size}³ | {number(e['seconds'])} | {e['seconds'] / base[1]['seconds']:.1f} | {n['samples']:,} | "
                f"{number(n['seconds'])} | {n['seconds'] / base[2]['seconds']:.1f} | {t['pairs']:,} | "
                f"{number(t['seconds'])} | {t['seconds'] / base[3]['seconds']:.1f} |"
            )
        lines.append("")
    lines += [f"![render time against work](scaling-{s['name']}.png)", ""]
    return lines


def _pipeline(doc: dict) -> list[str]:
    c, s = doc["cells"], doc["setting"]
    runs = sorted((int(k.split(".")[1]), v) for k, v in c.items() if k.startswith("pipeline.") and k[9:].isdigit())
    model = c.get("pipeline.model")
    if not runs:
        return []
    lines = [
        "## Pipeline: frame time against workers",
        "",
        f"Resident {s['size']}³ phantom, {s['pipeline_bits']}-bit key, {s['image']}² X-ray nearest, second frame "
        "of each cluster (N processes × 1 thread). Serial = client time before the first task (rays, "
        "footprints, graph, submission) + after the last (gather, assembly); tail = graph time after the "
        "last map task. Model: the traced graph replayed on N simulated workers (`hevr/bench/pipeline.py`)"
        + (f", fitted on the {model['from_workers']}-worker run." if model else "."),
        "",
        "| N | measured s | serial before / after s | tail s | busy s | model s | model efficiency |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    frames = model["frame"] if model else {}
    eff = model["efficiency"] if model else {}
    for n, v in runs:
        mark = " (more processes than cores)" if v.get("oversubscribed") else ""
        m = frames.get(str(n))
        lines.append(
            f"| {n}{mark} | {number(v['wall'])} | {number(v['serial_before'])} / {number(v['serial_after'])} | "
            f"{number(v['tail'])} | {number(v['busy'])} | {number(m) if m else '—'} | "
            f"{f'{eff[str(n)]:.0%}' if str(n) in eff else '—'} |"
        )
    for predicted in ("16", "64"):
        if predicted in frames:
            lines.append(
                f"| {predicted} (predicted) | — | — | — | — | {number(frames[predicted])} | {eff[predicted]:.0%} |"
            )
    return lines + [""]


def markdown(doc: dict) -> str:
    parts = (
        _header(doc)
        + goals_markdown(doc)
        + table1(doc)
        + table2(doc)
        + table3(doc)
        + limits(doc)
        + micro(doc)
        + naive(doc)
        + _scaling(doc)
        + _pipeline(doc)
    )
    todo = [b for b in _planned(doc) if b not in doc["blocks_done"]]
    if todo:
        parts += ["## Not (yet) run in this setting", "", ", ".join(todo), ""]
    secs = doc.get("block_seconds", {})
    parts += [
        f"Whole run: {sum(secs.values()) / 60:,.1f} min of measuring ("
        + ", ".join(f"{k} {secs[k] / 60:.1f}" for k in doc["blocks_done"] if k in secs)
        + " min).",
        "",
    ]
    return "\n".join(parts)


def _planned(doc: dict) -> list[str]:

    s = doc["setting"]
    known = {f.name for f in fields(BenchSettings)}
    values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in s.items() if k in known}
    st = BenchSettings(**values)
    return [name for name, _kind in block_names(st)]


def write_report(doc: dict, out: Path) -> Path:
    """Write the markdown (and the plot, if matplotlib is installed); return the markdown path."""

    name = doc["setting"]["name"]
    md = out / ("RESULTS.md" if name == "paper" else f"RESULTS-{name}.md")
    write_atomic(md, markdown(doc), overwrite=True, name="out", doing="writing the benchmark report")
    plot_scaling(doc, out / f"scaling-{name}.png")
    return md
