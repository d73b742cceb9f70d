"""Execute the example notebooks (notebooks/*.ipynb) top to bottom and check their results.

Each notebook ends with a cell tagged ``summary`` that prints one JSON object; the checks
below read it. The notebooks also assert their own invariants (decrypted images within
the error bound of the plaintext render, reused ray sums, no secret in the store), so a
failed assertion shows up as an errored cell.

The kernel is always this test's interpreter: a throw-away kernelspec named ``python3``
pointing at ``sys.executable`` is put first on ``JUPYTER_PATH``, so a ``python3``
kernelspec of another Python (e.g. ``~/.local/share/jupyter/kernels/python3``) cannot
hijack the run, and nothing has to be installed on a fresh CI machine.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
NOTEBOOKS = ["01_quickstart", "02_transfer_functions", "03_scaling"]
CELL_TIMEOUT = 300


def _load_build():
    import importlib.util

    spec = importlib.util.spec_from_file_location("hevr_notebooks_build", NOTEBOOK_DIR / "_build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def kernel_env(tmp_path_factory):
    """A private ``python3`` kernelspec running this interpreter, and a clean IPython dir."""
    base = tmp_path_factory.mktemp("jupyter")
    spec_dir = base / "data" / "kernels" / "python3"
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "Python 3 (hevr tests)",
        "language": "python",
    }))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JUPYTER_PATH", str(base / "data"))
        mp.setenv("IPYTHONDIR", str(base / "ipython"))   # no user profile/startup files
        mp.setenv("JUPYTER_RUNTIME_DIR", str(base / "runtime"))   # connection files
        mp.delenv("MPLBACKEND", raising=False)           # let ipykernel pick the inline backend
        yield


def _summary(nb) -> dict:
    cells = [c for c in nb.cells if "summary" in c.get("metadata", {}).get("tags", [])]
    assert len(cells) == 1, "expected exactly one cell tagged 'summary'"
    text = "".join(o.get("text", "") for o in cells[0].outputs
                   if o.output_type == "stream" and o.name == "stdout")
    return json.loads(text.strip().splitlines()[-1])


def _check_quickstart(s: dict) -> None:
    assert s["image_shape"] == [40, 40]
    assert s["render_stats"]["reused_ray_sums"] is False and s["render_stats"]["map_tasks"] > 0
    # The encrypted render matches the plaintext render to within the proven bound,
    # and the bound is small against the image's values (X-ray of uint8 data).
    assert s["max_error"] <= s["error_bound"]
    assert s["reference_max"] > 10 and s["max_error"] < 1e-2 * s["reference_max"]


def _check_transfer(s: dict) -> None:
    labels = [r["label"] for r in s["images"]]
    assert labels[:4] == ["X-ray", "emphasis 0.653", "emphasis 0.331", "emphasis 0.781"]
    assert len(labels) == 8 and all(lab.startswith("TF ") for lab in labels[4:])
    for r in s["images"]:
        assert r["max_error"] <= r["bound"], r
    # The first emphasis image computes the vector ray sums; every later one reuses them.
    first = s["images"][1]
    assert first["reused_ray_sums"] is False and first["map_tasks"] > 0
    for r in s["images"][2:]:
        assert r["reused_ray_sums"] is True and r["map_tasks"] == 0, r
    rc = s["recolour"]
    assert rc["reused_ray_sums"] is True and rc["map_tasks"] == 0 and rc["calls"] == 2


def _check_scaling(s: dict) -> None:
    assert set(s["worker_seconds"]) == {"1", "2"}
    assert all(v > 0 for v in s["worker_seconds"].values())
    assert s["speedup"]["1"] == 1.0 and s["speedup"]["2"] > 0
    bricks = s["bricks"]
    assert [r["brick"] for r in bricks] == [6, 8, 12]
    tasks = [r["map_tasks"] for r in bricks]
    assert tasks == sorted(tasks, reverse=True) and len(set(tasks)) == 3, tasks
    assert all(r["map_tasks"] <= r["bricks"] for r in bricks)
    assert s["brick_images_identical"] is True   # exact integer ray sums: bricking changes nothing
    keys = s["keys"]
    assert [r["bits"] for r in keys] == [256, 512, 1024]
    assert all(r["render_s"] > 0 and r["decrypt_s"] > 0 and r["volume_us_per_voxel"] > 0 for r in keys)


CHECKS = {
    "01_quickstart": _check_quickstart,
    "02_transfer_functions": _check_transfer,
    "03_scaling": _check_scaling,
}


def test_notebooks_are_built_and_clean():
    """The committed notebooks equal the generator's output (hence carry no outputs)."""
    build = _load_build()
    expected = build.build()
    assert sorted(expected) == sorted(f"{n}.ipynb" for n in NOTEBOOKS)
    for name, text in expected.items():
        path = NOTEBOOK_DIR / name
        assert path.read_text(encoding="utf-8") == text, f"{name} is stale: run python notebooks/_build.py"
        nb = nbformat.reads(text, as_version=4)
        for cell in nb.cells:
            if cell.cell_type == "code":
                assert cell.outputs == [] and cell.execution_count is None, f"{name}: cell {cell.id} has outputs"


@pytest.mark.slow
@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_runs(name, kernel_env, record_property):
    from nbclient import NotebookClient

    nb = nbformat.read(NOTEBOOK_DIR / f"{name}.ipynb", as_version=4)
    client = NotebookClient(nb, timeout=CELL_TIMEOUT, startup_timeout=120, kernel_name="python3",
                            allow_errors=False, resources={"metadata": {"path": str(NOTEBOOK_DIR)}})
    t0 = time.perf_counter()
    client.execute()   # raises CellExecutionError on the first failing cell
    seconds = time.perf_counter() - t0
    record_property("seconds", round(seconds, 1))
    print(f"{name}: {seconds:.1f} s")

    for cell in nb.cells:
        if cell.cell_type == "code":
            errors = [o for o in cell.outputs if o.output_type == "error"]
            assert not errors, f"{name}: cell {cell.id} raised {errors[0].ename}: {errors[0].evalue}"
            assert cell.execution_count is not None, f"{name}: cell {cell.id} did not run"
    CHECKS[name](_summary(nb))
