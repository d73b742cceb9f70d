"""Issue 24, items 1 and 6, on the command line: no command writes over an existing file unless
``--force`` (exit 2, one line naming the option and telling ``--force``), the demo replaces
only what it wrote itself, bench only its own run's files (``--resume``/``--force``), and a
refusal of the operating system while writing (disk full, file-size limit, read-only
filesystem) is one line naming the path, exit 1, with nothing half-written left.

256-bit keys and tiny phantoms: fast, NOT secure.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.cli.exits import exit_code
from hevr.cli.main import main
from hevr.core import files as _files

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def refused(capsys, option: str, path: Path, *argv) -> None:
    """The command exits 2 with one line: ``OPTION: expected no file at PATH (pass --force …)``."""
    code, _, err = run(capsys, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"hevr: error: {option}: expected no file at ") and str(path) in lines[0], err
    assert "(pass --force to replace it)" in lines[0], err


def _temporaries(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if ".hevr-tmp-" in p.name]


@pytest.fixture(scope="module")
def work(cli_store):
    d = cli_store("force", size=8, dims=2)
    assert (
        main(
            [
                "render",
                str(d / "vol.zarr"),
                "--out",
                str(d / "f.hevr"),
                "--size",
                "6x5",
                "--keep-sums",
                str(d / "f.hevrsums"),
                "-q",
            ]
        )
        == 0
    )
    return d


def test_render_slice_recolour_never_write_over_a_key(work, tmp_path, capsys):
    key = tmp_path / "key.json"
    key.write_bytes((work / "key.json").read_bytes())
    key.chmod(0o600)
    before = key.read_bytes()
    small = ["--size", "6x5", "-q"]
    refused(capsys, "--out", key, "render", work / "vol.zarr", "--out", key, *small)
    refused(capsys, "--out", key, "slice", work / "vol.zarr", "--out", key, "--axial", "3", *small)
    refused(capsys, "--out", key, "recolour", work / "f.hevrsums", "--out", key, "--mode", "xray", "-q")
    assert key.read_bytes() == before and stat.S_IMODE(key.stat().st_mode) == 0o600
    frame = tmp_path / "a.hevr"
    frame.write_bytes(b"older")
    for argv in (
        ["render", work / "vol.zarr", *small],
        ["slice", work / "vol.zarr", "--axial", "3", *small],
        ["recolour", work / "f.hevrsums", "--mode", "xray", "-q"],
    ):
        code, _, err = run(capsys, *argv, "--out", frame, "--force")
        assert code == 0, err
        assert hevr.load_image(frame).n_ciphertexts > 0
    assert _temporaries(tmp_path) == []


def test_keep_sums_is_refused_before_the_render(work, tmp_path, capsys):
    sums = tmp_path / "s.hevrsums"
    sums.write_text("mine")
    refused(
        capsys,
        "--keep-sums",
        sums,
        "render",
        work / "vol.zarr",
        "--out",
        tmp_path / "b.hevr",
        "--size",
        "6x5",
        "--keep-sums",
        sums,
        "-q",
    )
    assert sums.read_text() == "mine" and not (tmp_path / "b.hevr").exists()
    code, _, err = run(
        capsys,
        "render",
        work / "vol.zarr",
        "--out",
        tmp_path / "b.hevr",
        "--size",
        "6x5",
        "--keep-sums",
        sums,
        "--force",
        "-q",
    )
    assert code == 0, err
    assert sums.read_bytes()[:8] == b"HEVRSUMS"


def test_decrypt_png_and_npy(work, tmp_path, capsys):
    png, npy = tmp_path / "f.png", tmp_path / "f.npy"
    png.write_text("mine")
    refused(capsys, "--out", png, "decrypt", work / "f.hevr", "--key", work / "key.json", "--out", png, "-q")
    npy.write_text("mine too")
    refused(
        capsys,
        "--npy",
        npy,
        "decrypt",
        work / "f.hevr",
        "--key",
        work / "key.json",
        "--out",
        tmp_path / "g.png",
        "--npy",
        npy,
        "-q",
    )
    assert png.read_text() == "mine" and npy.read_text() == "mine too" and not (tmp_path / "g.png").exists()
    code, _, err = run(
        capsys, "decrypt", work / "f.hevr", "--key", work / "key.json", "--out", png, "--npy", npy, "--force", "-q"
    )
    assert code == 0, err
    arr = np.load(npy)
    assert arr.shape == (5, 6) and png.read_bytes()[:4] == b"\x89PNG"
    code, _, err = run(
        capsys,
        "decrypt",
        work / "f.hevr",
        "--key",
        work / "key.json",
        "--out",
        tmp_path / "h.png",
        "--npy",
        tmp_path / "h.png",
        "-q",
    )
    assert code == 2 and "--npy: expected another file than --out" in err


@pytest.mark.parametrize(
    "step, code, force",
    [("write", errno.ENOSPC, False), ("link", errno.EROFS, False), ("replace", errno.EFBIG, True)],
    ids=["ENOSPC", "EROFS", "EFBIG"],
)
def test_a_failed_write_is_one_line_and_exit_1(work, tmp_path, capsys, monkeypatch, step, code, force):
    png, frame = tmp_path / "x.png", tmp_path / "x.hevr"
    if force:
        png.write_text("old png")
        frame.write_text("old frame")

    def fail(*args, **kwargs):
        raise OSError(code, "injected")

    name = errno.errorcode[code]
    extra = ["--force"] if force else []
    with monkeypatch.context() as m:
        m.setattr(_files.os, step, fail)
        for argv, path in (
            (["decrypt", work / "f.hevr", "--key", work / "key.json", "--out", png], png),
            (["render", work / "vol.zarr", "--out", frame, "--size", "6x5"], frame),
        ):
            got, _, err = run(capsys, *argv, *extra, "-q")
            lines = [line for line in err.splitlines() if line.strip()]
            assert got == 1 and len(lines) == 1, err
            assert f"{path}: injected ({name})" in lines[0] and lines[0].startswith("hevr: error: writing"), err
    if force:
        assert png.read_text() == "old png" and frame.read_text() == "old frame"
    else:
        assert not png.exists() and not frame.exists()
    assert _temporaries(tmp_path) == []


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EFBIG, errno.EROFS, errno.ENAMETOOLONG], ids=errno.errorcode.get)
def test_filesystem_errors_are_exit_1(code):
    assert exit_code(hevr.FileSystemError(code, "writing the image", "/d/a.hevr")) == 1


def test_a_url_like_local_name_is_a_usage_error(work, tmp_path, capsys):
    code, _, err = run(capsys, "render", work / "vol.zarr", "--out", f"{tmp_path}/x://y.hevr", "--size", "6x5", "-q")
    assert code == 2 and err.startswith("hevr: error: --out: expected a local path or an fsspec URL"), err


# -- demo and bench ------------------------------------------------------------------------------
DEMO = ["--size", "6", "--image", "6x6", "--bits", "256", "--workers", "1", "-q"]


def test_demo_replaces_only_what_it_wrote(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "key.json").write_text("the user's key")
    (out / "demo-key.json").write_text("the user's file, by chance named like the demo's key")
    refused(capsys, "--out", out / "demo-key.json", "demo", "--out", out, *DEMO)
    assert sorted(p.name for p in out.iterdir()) == ["demo-key.json", "key.json"]  # nothing done
    (out / "demo-key.json").unlink()
    code, _, err = run(capsys, "demo", "--out", out, *DEMO)
    assert code == 0, err
    assert (out / "key.json").read_text() == "the user's key"
    assert stat.S_IMODE((out / "demo-key.json").stat().st_mode) == 0o600
    first_key = (out / "demo-key.json").read_bytes()
    code, _, err = run(capsys, "demo", "--out", out, *DEMO)  # its own run: replaced without --force
    assert code == 0, err
    assert (out / "demo-key.json").read_bytes() != first_key
    assert stat.S_IMODE((out / "demo-key.json").stat().st_mode) == 0o600
    summary = out / "summary.json"
    summary.write_text(json.dumps({"edited": "by the user"}))  # no longer what the demo wrote
    refused(capsys, "--out", summary, "demo", "--out", out, *DEMO)
    assert json.loads(summary.read_text()) == {"edited": "by the user"}
    code, _, err = run(capsys, "demo", "--out", out, *DEMO, "--force")
    assert code == 0, err
    assert "images" in json.loads(summary.read_text()) and (out / "key.json").read_text() == "the user's key"
    assert _temporaries(out) == []


@pytest.mark.timeout(120)
def test_demo_with_a_fifo_as_its_record_refuses_and_never_blocks(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    os.mkfifo(out / ".hevr-outputs.json")  # reading it would block forever
    refused(capsys, "--out", out / ".hevr-outputs.json", "demo", "--out", out, *DEMO)
    assert sorted(p.name for p in out.iterdir()) == [".hevr-outputs.json"]


def test_bench_refuses_an_earlier_run_unless_resumed_or_forced(tmp_path, capsys):
    results = tmp_path / "results-quick.json"
    results.write_text(json.dumps({"setting": {"name": "quick"}}))
    refused(capsys, "--out", results, "bench", "--quick", "--out", tmp_path, "--only", "t1", "-q")
    assert json.loads(results.read_text()) == {"setting": {"name": "quick"}}
    code, _, err = run(capsys, "bench", "--quick", "--out", tmp_path, "--resume", "--force", "-q")
    assert code == 2 and "--resume, --force" in err
    results.unlink()
    (tmp_path / "RESULTS-quick.md").write_text("my notes")
    refused(capsys, "--out", tmp_path / "RESULTS-quick.md", "bench", "--quick", "--out", tmp_path, "--only", "t1", "-q")
    assert (tmp_path / "RESULTS-quick.md").read_text() == "my notes" and not results.exists()


@pytest.mark.timeout(120)
def test_bench_resume_with_a_fifo_as_its_results_refuses_and_never_blocks(tmp_path, capsys):
    os.mkfifo(tmp_path / "results-quick.json")  # reading it would block forever
    code, _, err = run(capsys, "bench", "--quick", "--out", tmp_path, "--resume", "--only", "t1", "-q")
    assert code == 2 and "--resume: expected the results of an earlier run (a regular file), got a FIFO" in err, err
