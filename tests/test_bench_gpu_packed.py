"""Issue 46's packed frame in the GPU proof (hevr/bench/gpu_packed.py, ``gpu_goals packed``) on the
host build, tiny sizes: what ``benchmarks/gpu-proof.sh goals`` / ``packed`` runs on a lent GPU must
work before one is lent — the packed store, its frames on the backend and on cpu (in this process
and on a LocalCluster), the identity and the bound checked, the rows and the table written — and a
backend off by one bit must be reported as such (exit status 1, "NO" in the table)."""

from __future__ import annotations

import json

import pytest

from hevr import backends
from hevr.backends import CudaHostBackend, register_backend
from hevr.bench import gpu_goals


@pytest.fixture(autouse=True)
def _known(tmp_path, monkeypatch):
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(tmp_path / "known.json"))


def _rows(out):
    return [json.loads(line) for line in (out / "goals.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("workers", [(1,), (1, 2)])
def test_the_packed_step_on_the_host_kernels(tmp_path, workers):
    out, work = tmp_path / "out", tmp_path / "work"
    ok = gpu_goals.run_step(
        "packed", out, work, backend="cuda-host", bits=256, repeats=1, workers=workers, packed_size=12, packed_image=12
    )
    assert ok is True
    rows = [r for r in _rows(out) if r["step"] == "packed"]
    enc = rows[0]
    assert enc["what"] == "encrypt packed" and enc["slots"] == 4 and enc["ciphertexts"] == 3 * 12 * 12
    assert enc["bytes"] > 0 and ("LocalCluster of 2" in enc["how"]) == (workers == (1, 2))
    frames = {r["what"]: r for r in rows[1:]}
    assert set(frames) == {f"packed {v} {s}" for v in ("general", "orbit") for s in ("nearest", "trilinear")} | {
        "packed general trilinear verified"
    }
    for r in frames.values():
        assert r["identical"] and r["within_bound"] and r["sha256"] == r["cpu_sha256"]
        assert r["backend"] == "cuda-host" and r["cpu_workers"] == max(workers) and r["seconds"] > 0
        assert r["ops"] == r["cpu_ops"] and r["ops"]["map"] > 0 and r["ops"]["pairs"] > 0 and r["decrypt_s"] > 0
    assert frames["packed orbit nearest"]["classes"] == 1 and frames["packed orbit nearest"]["ops"]["combine"] == 0
    general = frames["packed general trilinear"]
    assert general["classes"] > 1 and general["ops"]["combine_squarings"] > 0
    v = frames["packed general trilinear verified"]
    assert v["verified"] is True and v["verify_ops"]["map"] > 0 and v["verify_server_s"] > 0
    assert v["sha256"] == frames["packed general trilinear"]["sha256"]  # the same values, plus the tags' round
    assert all("verified" not in r for w, r in frames.items() if not w.endswith("verified"))
    text = (out / "goals.md").read_text()
    assert "Packed store (issue 46)" in text and "12³ phantom at 256 bits: S = 4" in text
    assert text.count("| yes | yes |") == 5 and "| NO" not in text and "general trilinear verified (cuda-host" in text


def test_a_wrong_backend_is_reported_not_hidden(tmp_path):
    """A backend whose Horner combine is off by one bit: rows say so, the table says NO, exit 1."""
    calls = []

    class Wrong(CudaHostBackend):
        name = "wrong"

        def pack(self, terms, exps, pack_bits, per_pack, offset, n):
            calls.append(1)
            out = super().pack(terms, exps, pack_bits, per_pack, offset, n)
            recs = self.to_bytes(out, (2 * int(n).bit_length() + 7) // 8)
            recs[0, -1] ^= 1
            return self.from_bytes(recs)

    register_backend("wrong", Wrong)
    out, work = tmp_path / "out", tmp_path / "work"
    try:
        code = gpu_goals.main(
            [
                "packed",
                "--out",
                str(out),
                "--work",
                str(work),
                "--backend",
                "wrong",
                "--bits",
                "256",
                "--repeats",
                "1",
                "--workers",
                "1",
                "--packed-size",
                "12",
                "--packed-image",
                "12",
            ]
        )
    finally:
        backends._FACTORIES.pop("wrong", None)
        backends._INSTANCES.pop("wrong", None)
    assert calls and code == 1
    frames = [r for r in _rows(out) if r["step"] == "packed" and r["what"] != "encrypt packed"]
    assert len(frames) == 5 and not any(r["identical"] for r in frames)
    assert frames[-1]["verified"] is False and "error" in frames[-1]  # the key holder's check refused it
    assert all(r["sha256"] != r["cpu_sha256"] for r in frames)
    assert "| NO |" in (out / "goals.md").read_text()


def test_the_table_has_no_packed_section_without_packed_rows(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    assert "Packed store" not in gpu_goals.table(out)
