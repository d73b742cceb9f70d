"""Smoke test of ``hevr bench --quick`` (numbers are not asserted) and of the report maths."""

from __future__ import annotations

import json

import pytest

from hevr.bench import report, report_cells
from hevr.bench.pipeline import predict, simulate
from hevr.bench.runner import rewrite_report, run_bench
from hevr.bench.settings import PAPER, QUICK, SETTINGS
from hevr.cli.main import main
from hevr.errors import ParameterError


@pytest.mark.slow
def test_bench_quick_cli_writes_everything(tmp_path, capsys):
    assert main(["bench", "--quick", "--out", str(tmp_path), "-q"]) == 0
    md = (tmp_path / "RESULTS-quick.md").read_text()
    doc = json.loads((tmp_path / "results-quick.json").read_text())
    assert (tmp_path / "scaling-quick.png").stat().st_size > 1000
    for heading in (
        "Table 1",
        "Table 2",
        "Table 3",
        "Against the limit",
        "python-paillier",
        "Scaling",
        "Pipeline: frame time against workers",
    ):
        assert heading in md
    assert "Not (yet) run" not in md
    cells = doc["cells"]
    for bits in QUICK.t1_bits:
        for tag in ("plain", "obf"):
            for sampling in ("nearest", "trilinear"):
                cell = cells[f"t1.{bits}.{tag}.{sampling}"]
                assert cell.get("within_bound") is True, (bits, tag, sampling, cell)
    for dims in QUICK.dims:
        assert cells[f"t2.{QUICK.t3_bits[0]}.{dims}"]["ciphertext_bytes"] == 12**3 * dims * 2 * QUICK.t3_bits[0] // 8
    assert cells["naive.phe"]["nearest"]["max_abs_err"] < 1e-6
    assert cells["naive.phe"]["nearest"]["max_abs_err_plain"] < 1e-6  # phe's naive render is right too
    assert doc["machine"]["cores"] >= 1 and doc["machine"]["versions"]["gmpy2"]
    # the pipeline block: traced frames on 1 and 2 workers, the model's predictions up to 64
    for n in (1, 2):
        run = cells[f"pipeline.{n}"]
        assert run["workers"] == n and run["image_stats"]["resident"] and run["tasks"] > 0
        assert 0 <= run["serial_before"] < run["wall"] and run["busy"] > 0
    model = cells["pipeline.model"]
    assert set(model["frame"]) == {"1", "2", "4", "8", "16", "32", "64"}
    assert all(0 < e <= 1.0 + 1e-9 for e in model["efficiency"].values())
    # the markdown is a pure function of the JSON
    (tmp_path / "RESULTS-quick.md").unlink()
    assert main(["bench", "--quick", "--report-only", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "RESULTS-quick.md").read_text() == md
    # a resumed run keeps every finished block and measures nothing again
    before = dict(doc["block_seconds"])
    run_bench("quick", tmp_path, resume=True, workers=0)
    again = json.loads((tmp_path / "results-quick.json").read_text())
    assert again["block_seconds"] == before and len(again["machines"]) == 2


def test_report_only_needs_results(tmp_path):
    with pytest.raises(ParameterError, match="out: expected .*results-quick.json"):
        rewrite_report("quick", tmp_path)


def test_only_rejects_unknown_block(tmp_path):
    with pytest.raises(ParameterError, match="only: expected some of micro"):
        run_bench("quick", tmp_path, only=("tables",), workers=0)


def test_resume_refuses_other_setting(tmp_path):
    (tmp_path / "results-quick.json").write_text(json.dumps({"setting": {"name": "paper"}}))
    with pytest.raises(ParameterError, match="resume: .* holds a 'paper' run"):
        run_bench("quick", tmp_path, resume=True, workers=0)


def test_settings_cover_the_paper():
    assert PAPER.size == 100 and PAPER.image == 150 and PAPER.workers_bits == 2048
    assert set(PAPER.t1_bits) >= {64, 128, 256, 512, 1024, 2048, 3072}
    assert set(SETTINGS) == {"quick", "default", "paper"}


def _doc(**cells):
    s = PAPER.to_dict()
    return {"setting": s, "cells": cells, "blocks_done": [], "machine": {}}


def test_goals_judged_from_cells():
    doc = _doc(
        **{
            "t1.2048.obf.nearest": {"seconds": 5.0},
            "t1.2048.obf.trilinear": {"seconds": 50.0},
            "scale.workers.1": {"seconds": 95.0},
            "t1.2048.obf.encrypt": {"seconds": 200.0},
        }
    )
    g = {goal: (value, ok) for _i, goal, _t, value, ok in report.goals(doc)}
    assert g["X-ray nearest render ≤ 6 s"] == (5.0, True)
    assert g["X-ray trilinear render ≤ 40 s"] == (50.0, False)
    assert g["2-worker speed-up ≥ 1.8× (trilinear X-ray)"] == (1.9, True)
    assert g["scalar encryption ≥ 100× faster than the paper (16,880 s)"] == (84.4, False)
    assert g["TF 4-dim, 4 colours, nearest ≤ 25 s"] == (None, None)


@pytest.mark.parametrize(
    "ours, theirs, text",
    [
        (2.0, 94.3, "2.00 / 94.3 (**47×**)"),
        (2.79, 3.49, "2.79 / 3.49 (**1.25×**)"),
        (10.0, 5.0, "10.0 / 5.00 (**0.50×**)"),
        (None, 3.0, "– / 3.00"),
        (1.5, None, "1.50"),
    ],
)
def test_cell_format(ours, theirs, text):
    assert report_cells.compare(ours, theirs) == text


def test_pipeline_model_replays_a_graph():
    # a fan-in of 8 unit tasks into one of 1 s: 2 workers need 4 + 1 s; 8 workers 1 + 1 s
    deps = {f"m{i}": [] for i in range(8)} | {"f": [f"m{i}" for i in range(8)]}
    dur = {f"m{i}": 1.0 for i in range(8)} | {"f": 1.0}
    assert simulate(deps, dur, 2) == 5.0 and simulate(deps, dur, 8) == 2.0 and simulate(deps, dur, 64) == 2.0
    trace = {
        "deps": deps,
        "durations": dur,
        "workers": 2,
        "span": 5.9,
        "serial_before": 0.1,
        "serial_after": 0.0,
        "tasks": 9,
    }
    out = predict(trace, [1, 2, 8])
    assert out["frame"]["2"] == pytest.approx(6.0, abs=1e-3)  # the overhead is fitted to the traced span
    assert out["efficiency"]["2"] < 1 and out["efficiency"]["8"] < out["efficiency"]["2"]
