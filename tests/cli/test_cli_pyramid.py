"""``hevr pyramid`` and ``hevr render --level``: the coarse frame decrypts to
``render_plain(..., level=L)`` within ``error_bound``; ``hevr info`` lists the levels; errors
start with the option and exit 2.

256-bit keys and tiny phantoms: fast, NOT secure.
"""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def store(cli_store):
    return cli_store("clipyr", size=12, store="v.zarr")


def test_pyramid_then_render_a_level(store, capsys, tmp_path):
    d = store
    code, out, err = _run(capsys, "pyramid", d / "v.zarr", "--levels", "2", "-q")
    assert code == 0, err
    assert "level 1: x×y×z = 6×6×6 voxels, complete" in out and "level 2: x×y×z = 3×3×3 voxels, complete" in out
    code, out, _ = _run(capsys, "pyramid", d / "v.zarr", "--levels", "1")
    assert code == 0 and "nothing to do" in out
    code, out, _ = _run(capsys, "info", d / "v.zarr")
    assert code == 0 and "level 2:" in out
    key = hevr.load_key(d / "key.json")
    ev = hevr.open_volume(d / "v.zarr")
    for level, mode, extra in [(1, "xray", []), (2, "tf", ["--tf", "0.3:red,0.8:blue"])]:
        code, out, err = _run(
            capsys,
            "render",
            d / "v.zarr",
            "--out",
            tmp_path / "f.hevr",
            "--level",
            level,
            "--size",
            "10x9",
            "--azimuth",
            "30",
            "--elevation",
            "15",
            *extra,
            "-q",
            "--force",
        )  # one frame file, rendered again per level
        assert code == 0, err
        assert f"pyramid level {level}" in out
        img = hevr.load_image(tmp_path / "f.hevr")
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=15, width=10, height=9)
        kw = {"nodes": [(0.3, "red"), (0.8, "blue")]} if mode == "tf" else {}
        ref = hevr.render_plain(hevr.phantom(12), cam, mode=mode, vector_dims=3, level=level, **kw)
        bound = hevr.error_bound(ev, cam, mode=mode, level=level, **kw)
        assert (np.abs(img.decrypt(key, nodes=kw.get("nodes")) - ref) <= bound).all()


def test_errors(store, capsys, tmp_path):
    d = store
    for argv, word in [
        (["pyramid", d / "none.zarr"], "STORE"),
        (["pyramid", d / "v.zarr", "--levels", "0"], "argument --levels"),
        (["render", d / "v.zarr", "--out", tmp_path / "x.hevr", "--level", "5"], "--level 5"),
        (["render", d / "v.zarr", "--out", tmp_path / "x.hevr", "--level", "x"], "argument --level"),
    ]:
        code, _, err = _run(capsys, *argv)
        assert code == 2, err
        line = err.strip().splitlines()
        assert len(line) == 1 and line[0].startswith(f"hevr: error: {word}"), err
