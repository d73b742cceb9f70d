"""The scaling figure: render time against work (samples × key size²), and 1 vs 2 workers."""

from __future__ import annotations

import io
import logging
from pathlib import Path

from ..core.files import write_file

log = logging.getLogger(__name__)


def _points(doc: dict) -> list[tuple[str, float, float]]:
    """(series, work, seconds) for every secure X-ray render of the run; work = (ray, voxel)
    pairs × the measured time of one modular multiplication ÷ workers: the render's arithmetic,
    which grows as samples × key size² once multiplications dominate."""
    c, s = doc["cells"], doc["setting"]
    pts = []
    for key, cell in c.items():
        parts = key.split(".")
        if not isinstance(cell, dict) or "samples" not in cell or "refused" in cell:
            continue
        if parts[0] == "t1" and parts[2] == "obf":
            series = f"Table 1, {parts[3]} ({s['size']}³, keys {min(s['t1_bits'])}–{max(s['t1_bits'])})"
        elif parts[0] == "scale" and parts[1] == "size":
            series = f"volume sizes, {parts[3]} ({s['scaling_bits']} bits)"
        else:
            continue
        work = cell["pairs"] * cell["mulmod_s"] / cell["workers"]
        pts.append((series, work, cell["seconds"]))
    return pts


def plot_scaling(doc: dict, path: Path) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("matplotlib is not installed: no %s (pip install 'hevr[notebook]')", path.name)
        return None
    pts = _points(doc)
    if not pts:
        return None
    runs = sorted(
        (int(k.split(".")[1]), v["wall"])
        for k, v in doc["cells"].items()
        if k.startswith("pipeline.") and k[9:].isdigit()
    )
    model = doc["cells"].get("pipeline.model")
    if runs:
        fig, (ax, bx, cx) = plt.subplots(1, 3, figsize=(15, 4.3), gridspec_kw={"width_ratios": [2.3, 1, 1.4]})
        _pipeline_panel(cx, runs, model, doc["setting"])
    else:
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.3), gridspec_kw={"width_ratios": [2.3, 1]})
    markers = iter("os^vDx")
    for series in sorted({p[0] for p in pts}):
        xs, ys = zip(*sorted((w, t) for name, w, t in pts if name == series))
        ax.loglog(xs, ys, marker=next(markers), label=series)
    lo = min(p[1] for p in pts)
    hi = max(p[1] for p in pts)
    ax.loglog([lo, hi], [lo, hi], "k:", lw=1, label="one modular multiplication per pair (time = work)")
    ax.set_xlabel("work = (ray, voxel) pairs × one `a·b mod n²` ÷ workers, s")
    ax.set_ylabel("render wall time, s")
    ax.set_title("Render time grows with the work")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    c, s = doc["cells"], doc["setting"]
    one = c.get("scale.workers.1")
    two = c.get(f"t1.{s['workers_bits']}.obf.trilinear")
    if one and two and "seconds" in one and "seconds" in two:
        bx.bar(["1 worker", f"{two['workers']} workers"], [one["seconds"], two["seconds"]], color=["#999", "#37c"])
        bx.set_title(
            f"Trilinear X-ray, {s['size']}³, {s['workers_bits']} bits\nspeed-up {one['seconds'] / two['seconds']:.2f}×",
            fontsize=9,
        )
        bx.set_ylabel("s")
    else:
        bx.axis("off")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=110, format="png")
    plt.close(fig)
    write_file(path, [buf.getbuffer()], overwrite=True, name="out", doing="writing the scaling plot")
    return path


def _pipeline_panel(ax, runs: list[tuple[int, float]], model: dict | None, s: dict) -> None:
    """Measured frame time against workers, and the model's prediction up to 64 workers."""
    ax.loglog([n for n, _ in runs], [t for _, t in runs], "o", color="#37c", label="measured")
    if model:
        ns = sorted(int(n) for n in model["frame"])
        ax.loglog(
            ns,
            [model["frame"][str(n)] for n in ns],
            "-",
            color="#c53",
            label=f"model (from {model['from_workers']} workers)",
        )
        t1 = model["frame"].get("1")
        if t1:
            ax.loglog(ns, [t1 / n for n in ns], "k:", lw=1, label="perfect scaling")
    ax.set_xlabel("workers")
    ax.set_ylabel("frame s")
    ax.set_title(f"Resident X-ray nearest, {s['size']}³, {s['pipeline_bits']} bits", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
