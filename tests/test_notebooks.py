"""The example notebooks: sources, committed outputs, and a full run of each.

Each notebook ``notebooks/NN_name.ipynb`` is built from the jupytext percent script
``notebooks/NN_name.py`` by ``notebooks/_build.py`` and committed *with* its outputs. The
fast tests check that the committed files are in sync with their sources (what
``python notebooks/_build.py --check`` does), that each shows at least one picture, and
that no output shows a path of the build machine or key material. The slow tests execute
every notebook top to bottom with the build script's own executor (a fresh kernel of
this interpreter; a probe afterwards collects the private keys alive in the kernel and
the run fails if an output shows one) and check the JSON printed by its cell tagged
``summary``. The notebooks also assert their own invariants (decrypted images within the
error bound of the plaintext render, reused ray sums, no secret in the store), so a
failed assertion shows up as an errored cell.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("jupytext")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
NOTEBOOKS = ["01_quickstart", "02_transfer_functions", "03_scaling", "04_slices_pyramid_gradient", "05_remote_server"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _load_build():
    import importlib.util

    spec = importlib.util.spec_from_file_location("hevr_notebooks_build", NOTEBOOK_DIR / "_build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


build = _load_build()


def _committed(name: str):
    return nbformat.read(NOTEBOOK_DIR / f"{name}.ipynb", as_version=4)


def _summary(nb) -> dict:
    cells = [c for c in nb.cells if "summary" in c.get("metadata", {}).get("tags", [])]
    assert len(cells) == 1, "expected exactly one cell tagged 'summary'"
    text = "".join(o.get("text", "") for o in cells[0].outputs if o.output_type == "stream" and o.name == "stdout")
    return json.loads(text.strip().splitlines()[-1])


def _pngs(nb) -> list[bytes]:
    return [
        base64.b64decode(o.data["image/png"])
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
        if "image/png" in o.get("data", {})
    ]


def _check_quickstart(s: dict) -> None:
    assert s["image_shape"] == [40, 40]
    assert s["render_stats"]["reused_ray_sums"] is False and s["render_stats"]["map_tasks"] > 0
    # The encrypted render matches the plaintext render to within the proven bound,
    # and the bound is small against the image's values (X-ray of uint8 data).
    assert s["max_error"] <= s["error_bound"]
    assert s["reference_max"] > 10 and s["max_error"] < 1e-2 * s["reference_max"]


def _check_transfer(s: dict) -> None:
    labels = [r["label"] for r in s["images"]]
    assert labels[:4] == ["X-ray", "emphasis 0.331", "emphasis 0.653", "emphasis 0.781"]
    assert len(labels) == 8 and all(lab.startswith("TF ") for lab in labels[4:])
    for r in s["images"]:
        assert r["max_error"] <= r["bound"], r
    # The first emphasis image computes the vector ray sums; every later one reuses them.
    first = s["images"][1]
    assert first["reused_ray_sums"] is False and first["map_tasks"] > 0
    for r in s["images"][2:]:
        assert r["reused_ray_sums"] is True and r["map_tasks"] == 0, r
    # hevr.Viewer driven from code: its first frame (the view of section 4) and every colour,
    # node and mode change re-colour cached sums; the new camera (frame 5) runs the map step.
    v = s["viewer"]
    assert v["frames"] == 7
    assert [m > 0 for m in v["map_tasks"]] == [False, False, False, False, False, True, False], v
    assert v["reused"] == [True, True, True, True, True, False, True], v


def _check_scaling(s: dict) -> None:
    assert set(s["worker_seconds"]) == {"1", "2"}
    assert all(v > 0 for v in s["worker_seconds"].values())
    assert s["speedup"]["1"] == 1.0 and s["speedup"]["2"] > 0
    bricks = s["bricks"]
    assert [r["brick"] for r in bricks] == [6, 8, 12]
    tasks = [r["map_tasks"] for r in bricks]
    assert tasks == sorted(tasks, reverse=True) and len(set(tasks)) == 3, tasks
    assert all(r["map_tasks"] <= r["bricks"] for r in bricks)
    assert s["brick_images_identical"] is True  # exact integer ray sums: bricking changes nothing
    keys = s["keys"]
    assert [r["bits"] for r in keys] == [256, 512, 1024]
    assert all(r["render_s"] > 0 and r["decrypt_s"] > 0 and r["volume_us_per_voxel"] > 0 for r in keys)


def _check_beyond(s: dict) -> None:
    planes = {r["plane"] for r in s["slices"]}
    assert planes == {"axial 12", "coronal 12", "sagittal 12", "oblique", "slab of 5"}
    assert {r["sampling"] for r in s["slices"]} == {"nearest", "trilinear"}
    tasks = [r["map_tasks"] for r in sorted(s["levels"], key=lambda r: r["level"])]
    assert len(tasks) == 3 and tasks[0] > tasks[1] > tasks[2] >= 1, tasks  # coarser levels, fewer bricks
    grads = [(r["volume"], r["gradient"]) for r in s["gradient"]]
    assert ("phantom", False) in grads and ("phantom", True) in grads
    assert ("brain MRI", False) in grads and ("brain MRI", True) in grads  # the real scan nibabel ships
    v = s["viewer"]
    assert v["moving_level"] == 1 and v["still_level"] == 0 and v["moving_map_tasks"] >= 1
    assert s["pyramid_over_encrypt"] > 0


def _check_remote(s: dict) -> None:
    assert s["tf_error_ok"] is True and s["same_bytes"] is True  # the in-process frame, byte for byte
    assert s["slice_shape"][0] > 0 and s["streamed_ciphertexts"] > 0 and s["render_s"] > 0


CHECKS = {
    "01_quickstart": _check_quickstart,
    "02_transfer_functions": _check_transfer,
    "03_scaling": _check_scaling,
    "04_slices_pyramid_gradient": _check_beyond,
    "05_remote_server": _check_remote,
}


# -- sources and committed notebooks (fast) ------------------------------------------------------


def test_sources_are_python_with_one_summary_cell():
    """Each notebook's source is a compilable Python file; its summary cell is tagged."""
    srcs = build.sources()
    assert sorted(srcs) == NOTEBOOKS
    for name, path in srcs.items():
        text = path.read_text(encoding="utf-8")
        compile(text, str(path), "exec")  # SyntaxError if the source is not Python
        nb = build.notebook_from_source(path)
        code = [c for c in nb.cells if c.cell_type == "code"]
        assert len(code) >= 5 and any(c.cell_type == "markdown" for c in nb.cells), name
        assert [c for c in code if "summary" in c.metadata.get("tags", [])] == [code[-1]], name


def test_committed_notebooks_match_their_sources():
    """``python notebooks/_build.py --check`` would pass: same cells, executed, clean outputs."""
    assert build.check() == []
    assert build.main(["--check"]) == 0


def test_check_detects_stale_and_unexecuted_notebooks(tmp_path):
    """The --check logic is not vacuous: edits to code, markdown or tags and missing outputs show."""
    src = tmp_path / "01_quickstart.py"
    shutil.copy(NOTEBOOK_DIR / "01_quickstart.py", src)
    shutil.copy(NOTEBOOK_DIR / "01_quickstart.ipynb", tmp_path / "01_quickstart.ipynb")
    assert build.check_notebook("01_quickstart", src) == []

    original = src.read_text(encoding="utf-8")
    edits = [
        original.replace("KEY_BITS = 512", "KEY_BITS = 1024", 1),  # code
        original.replace("# # hevr quick start", "# # hevr quickstart", 1),  # markdown
        original.replace('# %% tags=["summary"]', "# %%", 1),  # tags
    ]
    for edited in edits:
        assert edited != original
        src.write_text(edited, encoding="utf-8")
        problems = build.check_notebook("01_quickstart", src)
        assert any("cells differ" in p for p in problems), problems
    src.write_text(original, encoding="utf-8")

    nb = nbformat.read(tmp_path / "01_quickstart.ipynb", as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    nbformat.write(nb, tmp_path / "01_quickstart.ipynb")
    problems = build.check_notebook("01_quickstart", src)
    assert any("was not executed" in p for p in problems), problems


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_committed_notebook_shows_pictures(name):
    """At least one PNG output, so that a code host shows the figures without running anything."""
    from PIL import Image

    pngs = _pngs(_committed(name))
    assert pngs, f"{name}.ipynb has no image/png output: run python notebooks/_build.py {name}"
    for png in pngs:
        assert png.startswith(PNG_MAGIC)
        with Image.open(io.BytesIO(png)) as im:
            assert im.width >= 100 and im.height >= 100, im.size


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_committed_summary_passes_the_checks(name):
    """The committed outputs are those of a run that passes the same checks as a fresh run."""
    CHECKS[name](_summary(_committed(name)))


def test_output_problems_flags_paths_and_key_numbers():
    """Guard for the output check used by the build and by --check."""
    p = 2**127 - 1  # a (Mersenne) prime, standing in for a key's secret prime
    bad = [
        f"temporary files in {ROOT / 'x'}",
        "EncryptedVolume('/tmp/hevr-quickstart-abc/phantom.zarr')",
        "written to /home/someone/key.json",
        f"p = {p}",
        f"hex {p:x}",
        "n = 1234567890123456789012345678901234567890",
    ]
    clean = [
        "hevr 0.1.0 - temporary files in WORKDIR = hevr-quickstart-5rwpvptv",
        "EncryptedVolume('WORKDIR/phantom.zarr', shape=(24, 24, 24), key=1a04dfd2cf0e666f…)",
        "<Client: 'tcp://127.0.0.1:41201' processes=2 threads=2, memory=23.54 GiB>",
        "69120 ciphertexts in 11.02 s (159 us each), bricks: (2, 2, 2)",
    ]

    def notebook(text):
        nb = nbformat.v4.new_notebook()
        cell = nbformat.v4.new_code_cell("print(x)")
        cell.id = "t-00"
        cell.outputs = [nbformat.v4.new_output("stream", name="stdout", text=text)]
        nb.cells.append(cell)
        return nb

    for text in bad:
        assert build.output_problems(notebook(text)), text
    for text in clean:
        assert build.output_problems(notebook(text), [str(p)]) == [], text
    # The secret is found in decimal and hex even where the generic rules would not see it,
    # and no message repeats it (build logs are not secret).
    for text in (f"x{p}y", f"{p:X}", f"p={p} q={p:x}"):
        problems = build.output_problems(notebook(text), [str(p)])
        assert any("private key number" in m for m in problems), text
        assert not any(str(p) in m or f"{p:x}" in m.lower() for m in problems), problems


# -- full runs (slow) ---------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_runs(name, record_property):
    nb = _committed(name)
    t0 = time.perf_counter()
    build.execute(nb)  # CellExecutionError on the first failing cell; NotebookOutputError on a leak
    seconds = time.perf_counter() - t0
    record_property("seconds", round(seconds, 1))
    print(f"{name}: {seconds:.1f} s")

    assert all(c.get("id") != "probe" for c in nb.cells)  # the probe is never kept
    for cell in nb.cells:
        if cell.cell_type == "code":
            errors = [o for o in cell.outputs if o.output_type == "error"]
            assert not errors, f"{name}: cell {cell.id} raised {errors[0].ename}: {errors[0].evalue}"
            assert cell.execution_count is not None, f"{name}: cell {cell.id} did not run"
    assert _pngs(nb), f"{name}: the run drew no figure"
    CHECKS[name](_summary(nb))


@pytest.mark.slow
def test_execute_rejects_a_notebook_that_prints_a_private_prime():
    """The probe in the kernel finds the live private key; a printed prime fails the build."""
    nb = nbformat.v4.new_notebook()
    for i, src in enumerate(
        [
            (
                "import warnings\nimport hevr\nwarnings.simplefilter('ignore', hevr.InsecureKeyWarning)\n"
                "pub, priv = hevr.generate_keypair(256)"
            ),
            "print('modulus bits:', pub.bits)",
            "print('q =', priv.q)",
        ]
    ):
        cell = nbformat.v4.new_code_cell(src)
        cell.id = f"t-{i:02d}"
        nb.cells.append(cell)
    with pytest.raises(build.NotebookOutputError) as err:
        build.execute(nb, timeout=120)
    message = str(err.value)
    # "private key number" comes only from the numbers the probe collected in the kernel.
    assert "cell t-02: output shows a private key number" in message, message
    assert "cell t-01" not in message, message
    assert not build.LONG_DECIMAL.search(message) and not build.LONG_HEX.search(message), message
