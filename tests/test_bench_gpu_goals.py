"""Issue 40's goal table (hevr/bench/gpu_goals.py) on the host build: every step, tiny sizes.

What a GPU session runs (``benchmarks/gpu-proof.sh goals``) must work before a device is lent: the
stores, the backend's frames, the cpu curve and the table, with the identity of the backend's and
``cpu``'s images and the error bound checked on the way."""

from __future__ import annotations

import json

import pytest

import hevr
from hevr.bench import gpu_goals


@pytest.fixture(autouse=True)
def _known(tmp_path, monkeypatch):
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(tmp_path / "known.json"))


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
def test_every_step_on_the_host_kernels_writes_the_goal_table(tmp_path):
    out, work = tmp_path / "out", tmp_path / "work"
    kw = dict(backend="cuda-host", size=8, tf_size=6, image=8, bits=256, repeats=1, workers=(1, 2))
    gpu_goals.run_step("stores", out, work, owner_kernels=True, **kw)  # owner.cuh's host build, in process
    gpu_goals.run_step("frames", out, work, **kw)
    gpu_goals.run_step("curve", out, work, **kw)
    gpu_goals.run_step("throughput", out, work, quick=True, **kw)
    rows = [json.loads(line) for line in (out / "goals.jsonl").read_text().splitlines()]
    assert {r["step"] for r in rows} == {"machine", "stores", "frames", "curve", "throughput"}
    tp = {r["what"]: r for r in rows if r["step"] == "throughput"}
    assert set(tp) == {"products", "pairs"} and all(
        r["end_to_end_per_s"] > 0 and r["kernels_per_s"] > 0 for r in tp.values()
    )
    stores = [r for r in rows if r["step"] == "stores"]
    assert [r["what"] for r in stores] == ["encrypt scalar", "encrypt tf"]
    assert stores[0]["ciphertexts"] == 8**3 and stores[1]["ciphertexts"] == 6**3 * 5
    assert "owner kernels" in stores[0]["how"]
    frames = {r["what"]: r for r in rows if r["step"] == "frames"}
    assert set(frames) == {"frame xray nearest", "frame xray trilinear", "frame tf trilinear"}
    assert all(r["within_bound"] for r in frames.values())
    curve = [r for r in rows if r["step"] == "curve"]
    assert [(r["workers"], r["what"]) for r in curve] == [
        (1, "frame xray nearest"),
        (2, "frame xray nearest"),
        (2, "frame xray trilinear"),
        (2, "frame tf trilinear"),
    ]
    for r in curve[1:]:  # the identical-image rule: cuda-host's frames are cpu's, byte for byte
        assert r["sha256"] == frames[r["what"]]["sha256"]
    text = (out / "goals.md").read_text()
    assert "identical to cpu" in text and "NOT identical" not in text and "OUT OF BOUND" not in text
    assert "8³ owner encryption" in text and "efficiency at 2 workers" in text
    assert text.count("| 2 |") == 3
    assert (
        "| 4096-bit products/s, kernels only | ≥ 1e8 | " in text
        and "| — | — |" not in text.split("products/s, kernels")[1].split("\n")[0]
    )


def test_the_table_says_what_was_not_measured_and_names_a_mismatch(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    assert "| 100³ owner encryption, s | ≤ 3 | — | — |" in gpu_goals.table(out)
    rows = [
        {
            "step": "frames",
            "what": "frame xray nearest",
            "backend": "cuda",
            "size": 100,
            "image": 150,
            "seconds": 0.5,
            "sha256": "a",
            "within_bound": False,
        },
        {"step": "curve", "what": "frame xray nearest", "workers": 16, "seconds": 0.2, "sha256": "b"},
        {"step": "curve", "what": "frame xray nearest", "workers": 1, "seconds": 3.2, "sha256": "b"},
    ]
    (out / "goals.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    text = gpu_goals.table(out)
    assert "NOT identical to cpu" in text and "OUT OF BOUND" in text
    assert "| frame: xray nearest | ≤ 0.10 | 0.5" in text and text.split("frame: xray nearest")[1].split("\n")[
        0
    ].endswith("| no |")
    assert "| cpu nearest, efficiency at 16 workers | ≥ 0.80 | 1 | yes |" in text  # 3.2 / (16 · 0.2)


def test_an_unknown_step_and_a_missing_key_are_named(tmp_path):
    with pytest.raises(hevr.ParameterError, match="step: expected one of"):
        gpu_goals.run_step("nope", tmp_path / "o", tmp_path / "w")
    with pytest.raises(FileNotFoundError, match="run the stores step first"):
        gpu_goals.run_step("frames", tmp_path / "o", tmp_path / "w", backend="cuda-host")
