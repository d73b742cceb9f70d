"""The benchmarks page's plots and tables, made at build time from the committed results in
``benchmarks/`` (never committed themselves): written to ``docs/_generated/bench/`` (git-ignored),
which ``benchmarks.md`` shows and includes.

* ``table1.png``: the paper's Table 1 (X-ray, with the mask) beside ours, encrypt / render /
  decrypt against the key size, from ``benchmarks/results-paper.json`` and the published figures
  (:mod:`hevr.bench.paper`);
* ``table3.png``: Table 3 (transfer function, 4-dim encoding) the same way;
* ``scaling.png``: ``hevr bench``'s own scaling figure (:func:`hevr.bench.plot.plot_scaling`);
* ``packed.png``: packed against per-voxel stores (``benchmarks/results-packed-2048.json``);
* ``report.md``: ``hevr bench``'s report of the same run (:func:`hevr.bench.report.markdown`),
  every cell ``ours / paper``, its headings one level down.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

from sphinx.application import Sphinx
from sphinx.util import logging

log = logging.getLogger(__name__)

OURS, THEIRS = "#37c", "#c53"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    """Write the figure unless the file already holds the same bytes (no needless rebuild)."""
    buf = io.BytesIO()
    fig.savefig(buf, dpi=110, format="png", metadata={"Software": None})
    _plt().close(fig)
    data = buf.getvalue()
    if not path.exists() or path.read_bytes() != data:
        path.write_bytes(data)


def _cell(cells: dict, key: str, field: str) -> float | None:
    cell = cells.get(key)
    return cell.get(field) if isinstance(cell, dict) else None


def plot_table1(doc: dict, path: Path) -> None:
    from hevr.bench import paper

    plt = _plt()
    cells, bits = doc["cells"], doc["setting"]["t1_bits"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.9))
    for ax, (stage, field) in zip(axes, (("encrypt", "seconds"), ("render", "seconds"), ("decrypt", "decrypt_s"))):
        for sampling, style in (("nearest", "o"), ("trilinear", "s")):
            if stage == "encrypt" and sampling == "trilinear":
                continue  # one encryption serves both samplings
            key = "encrypt" if stage == "encrypt" else sampling
            label = "" if stage == "encrypt" else f" {sampling}"
            ours = [(b, _cell(cells, f"t1.{b}.obf.{key}", field)) for b in bits]
            ours = [(b, v) for b, v in ours if v is not None]
            theirs = sorted(paper.TABLE1[sampling][True][stage].items())
            if ours:
                ax.loglog(*zip(*ours), style + "-", color=OURS, label="hevr" + label, base=2)
            ax.loglog(*zip(*theirs), style + "--", color=THEIRS, label="paper" + label, base=2)
        ax.set_title(f"{stage} (with the mask)", fontsize=10)
        ax.set_xlabel("key size, bits")
        ax.set_ylabel("seconds")
        ax.set_yscale("log", base=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(
        f"Table 1: X-ray of the {doc['setting']['size']}³ phantom to {doc['setting']['image']}² pixels", fontsize=11
    )
    fig.tight_layout()
    _save(fig, path)


def plot_table3(doc: dict, path: Path) -> None:
    from hevr.bench import paper

    plt = _plt()
    cells, bits = doc["cells"], doc["setting"]["t3_bits"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.9))
    rows = (
        ("encrypt", lambda b: _cell(cells, f"t3.{b}.4.encrypt", "seconds"), paper.TABLE3_ENCRYPT[4]),
        ("render, 4 colours", lambda b: _cell(cells, f"t3.{b}.4.4", "seconds"), paper.TABLE3_RENDER[(4, 4)]),
        ("decrypt, 4 colours", lambda b: _cell(cells, f"t3.{b}.4.4", "decrypt_s"), paper.TABLE3_DECRYPT[(4, 4)]),
    )
    for ax, (title, ours_of, theirs) in zip(axes, rows):
        ours = [(b, ours_of(b)) for b in bits]
        ours = [(b, v) for b, v in ours if v is not None]
        if ours:
            ax.loglog(*zip(*ours), "o-", color=OURS, label="hevr", base=2)
        ax.loglog(*zip(*sorted(theirs.items())), "o--", color=THEIRS, label="paper", base=2)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("key size, bits")
        ax.set_ylabel("seconds")
        ax.set_yscale("log", base=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Table 3: transfer function on the 4-dim encoding (nearest)", fontsize=11)
    fig.tight_layout()
    _save(fig, path)


def plot_packed(doc: dict, path: Path) -> None:
    plt = _plt()
    labels, voxel, packed = [], [], []
    for size, run in doc["sizes"].items():
        for f in run["frames"]:
            labels.append(f"{size}³ {f['view']}\n{f['sampling']}")
            voxel.append(f["voxel"]["frame_s"])
            packed.append(f["packed"]["frame_s"])
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(labels)), 3.9))
    xs = range(len(labels))
    ax.bar([x - 0.2 for x in xs], voxel, 0.4, color="#999", label="per-voxel store")
    ax.bar([x + 0.2 for x in xs], packed, 0.4, color=OURS, label="packed store")
    ax.set_xticks(list(xs), labels, fontsize=7)
    ax.set_ylabel("frame seconds (render + decrypt)")
    ax.set_yscale("log")
    ax.set_title(f"Packed against per-voxel stores, {doc['bits']} bits, {doc['workers']}", fontsize=10)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def report_markdown(doc: dict) -> str:
    """``hevr bench``'s report of ``doc``, its title dropped, its headings one level down and its
    scaling plot left to the page (which shows it with a caption)."""
    from hevr.bench.report import markdown

    lines = markdown(doc).splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]
    lines = [line for line in lines if not line.startswith("![")]
    return "\n".join("#" + line if line.startswith("#") else line for line in lines) + "\n"


def generate(srcdir: Path, bench: Path) -> None:
    from hevr.bench.plot import plot_scaling

    out = srcdir / "_generated" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    paper_doc = json.loads((bench / "results-paper.json").read_text(encoding="utf-8"))
    plot_table1(paper_doc, out / "table1.png")
    plot_table3(paper_doc, out / "table3.png")
    scaling = out / "scaling.png"
    tmp = out / "scaling.new.png"
    if plot_scaling(paper_doc, tmp) is not None:
        if not scaling.exists() or scaling.read_bytes() != tmp.read_bytes():
            tmp.replace(scaling)
        else:
            tmp.unlink()
    plot_packed(json.loads((bench / "results-packed-2048.json").read_text(encoding="utf-8")), out / "packed.png")
    text = report_markdown(paper_doc)
    md = out / "report.md"
    if not md.exists() or md.read_text(encoding="utf-8") != text:
        md.write_text(text, encoding="utf-8")


def _generate(app: Sphinx) -> None:
    generate(Path(app.srcdir), Path(app.srcdir).parent / "benchmarks")


def setup(app: Sphinx) -> dict:
    app.connect("builder-inited", _generate)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
