"""``hevr render --keep-sums`` + ``hevr recolour`` write the frame a full ``hevr render`` writes,
bit for bit, without the map step; on a local cluster the CLI prints the dashboard link.

256-bit keys and tiny phantoms: fast, NOT secure.
"""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _ok(capsys, *argv) -> str:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


@pytest.fixture(scope="module")
def store(cli_store):
    return cli_store("recolour")


def _same_frame(a, b) -> None:
    x, y = hevr.load_image(a), hevr.load_image(b)
    assert x.shape == y.shape and x.exponent == y.exponent and x.per_pack == y.per_pack
    assert all(np.array_equal(p, q) for p, q in zip(x.ciphertexts, y.ciphertexts))


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_keep_sums_then_recolour_equals_a_full_render(store, tmp_path, capsys, sampling):
    d = store
    view = ["--size", "12x10", "--azimuth", "35", "--elevation", "15", "--sampling", sampling, "-q"]
    out = _ok(
        capsys,
        "render",
        d / "vol.zarr",
        "--out",
        tmp_path / "tf1.hevr",
        "--tf",
        "0.2:red,0.8:blue",
        "--keep-sums",
        tmp_path / "view.hevrsums",
        *view,
    )
    assert "hevr recolour" in out and (tmp_path / "view.hevrsums").stat().st_size > 0
    for extra in (["--tf", "0.1:lime,0.5:#ff0,0.9:white"], ["--density", "0.4"]):
        out = _ok(
            capsys, "recolour", tmp_path / "view.hevrsums", "--out", tmp_path / "re.hevr", *extra, "-q", "--force"
        )  # the loop writes re.hevr and full.hevr twice
        assert "no map step" in out and "12×10" in out.replace("x", "×")
        _ok(capsys, "render", d / "vol.zarr", "--out", tmp_path / "full.hevr", *extra, *view, "--force")
        _same_frame(tmp_path / "re.hevr", tmp_path / "full.hevr")
    _ok(
        capsys,
        "decrypt",
        tmp_path / "re.hevr",
        "--key",
        d / "key.json",
        "--out",
        tmp_path / "re.png",
        "-q",
        "--density",
        "0.4",
    )
    assert (tmp_path / "re.png").stat().st_size > 0


def test_xray_sums_default_to_xray_and_the_dashboard_link_is_printed(store, tmp_path, capsys):
    d = store
    out = _ok(
        capsys,
        "render",
        d / "vol.zarr",
        "--out",
        tmp_path / "x.hevr",
        "--size",
        "8x8",
        "--keep-sums",
        tmp_path / "x.hevrsums",
        "--workers",
        "1",
        "-q",
    )
    assert "dashboard http" in out and "/status" in out
    _ok(capsys, "recolour", tmp_path / "x.hevrsums", "--out", tmp_path / "x2.hevr", "-q")
    _same_frame(tmp_path / "x.hevr", tmp_path / "x2.hevr")
