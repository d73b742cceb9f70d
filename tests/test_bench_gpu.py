"""``hevr bench --gpu`` (hevr.bench.gpu): the one command that proves the GPU backend. Here it runs
on the host build of the same kernels (``--gpu-backend cuda-host``): it must find every operation
and render identical, write gpu.md/gpu.json naming the device, and exit 1 when a backend is off by
one product; without CuPy the ``cuda`` backend is refused with what is missing."""

from __future__ import annotations

import json
import sys

import pytest

from hevr import backends
from hevr.backends import CudaHostBackend, register_backend
from hevr.cli.main import main


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
def test_gpu_bench_on_the_host_kernels_writes_its_report(tmp_path, capsys):
    assert main(["bench", "--gpu", "--quick", "--gpu-backend", "cuda-host", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "gpu.json").read_text())
    assert res["ok"] is True and res["device"] == "the host CPU (cuda-host)" and res["backend"] == "cuda-host"
    assert [r["bits"] for r in res["identity"]] == [64, 256, 1024, 2048]
    assert all(v is True for r in res["identity"] for k, v in r.items() if k not in ("bits", "values"))
    assert {r["case"] for r in res["render"]} == {"xray nearest", "xray trilinear", "tf nearest"}
    assert all(r["identical"] and r["within_bound"] for r in res["render"])
    assert all(r["resident_seconds"] > 0 for r in res["render"])
    assert set(res["throughput"]) == {"products", "pairs"}
    assert res["encryption"]["exact"] is True and res["encryption"]["values_per_s"] > 0
    assert all(r["products_per_s" if k == "products" else "pairs_per_s"] > 0 for k, r in res["throughput"].items())
    md = (tmp_path / "gpu.md").read_text()
    assert md.startswith("# hevr bench --gpu: the host CPU (cuda-host)") and "**all identical**" in md
    assert "operations against cpu: identical" in capsys.readouterr().out


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
def test_gpu_bench_exits_1_on_a_mismatch(tmp_path, monkeypatch):
    calls = []

    class Wrong(CudaHostBackend):
        name = "wrong"

        def segment_products(self, values, indptr, k, n2):
            calls.append(1)
            out = super().segment_products(values, indptr, k, n2)
            recs = self.to_bytes(out, (int(n2).bit_length() + 7) // 8)
            recs[0, -1] ^= 1  # one bit of one product
            return self.from_bytes(recs)

    register_backend("wrong", Wrong)
    try:
        assert main(["bench", "--gpu", "--quick", "--gpu-backend", "wrong", "--out", str(tmp_path)]) == 1
    finally:
        backends._FACTORIES.pop("wrong", None)
        backends._INSTANCES.pop("wrong", None)
    res = json.loads((tmp_path / "gpu.json").read_text())
    assert calls and res["ok"] is False
    assert not all(r["segment_products"] for r in res["identity"])
    assert "MISMATCH" in (tmp_path / "gpu.md").read_text()


def test_gpu_bench_without_cupy_says_what_is_missing(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "cupy", None)
    monkeypatch.delitem(backends._INSTANCES, "cuda", raising=False)
    code = main(["bench", "--gpu", "--out", str(tmp_path)])
    assert code != 0 and "pip install 'hevr[gpu]'" in capsys.readouterr().err
    assert not (tmp_path / "gpu.json").exists()


@pytest.mark.parametrize("extra", [["--paper"], ["--resume"], ["--only", "t1"]])
def test_gpu_bench_refuses_other_settings(tmp_path, extra, capsys):
    assert main(["bench", "--gpu", *extra, "--out", str(tmp_path)]) == 2
    assert "--gpu: expected alone" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["abacus", "cpu"])
def test_gpu_bench_names_an_unknown_backend(tmp_path, name, capsys):
    assert main(["bench", "--gpu", "--gpu-backend", name, "--out", str(tmp_path)]) == 2
    assert "--gpu-backend: expected one of cuda-host, cuda" in capsys.readouterr().err
    assert not (tmp_path / "gpu.json").exists()
