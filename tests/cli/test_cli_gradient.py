"""``hevr encrypt --gradient`` and ``--gradient`` on render, slice and recolour: the frames decrypt
to the plaintext references with gradient modulation; mistakes name ``--gradient`` and exit 2.

256-bit keys and tiny phantoms: fast, NOT secure.
"""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")
TF = "0.3:red,0.8:blue"
NODES = [(0.3, "red"), (0.8, "blue")]


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_gradient_end_to_end(tmp_path, capsys):
    assert main(["keygen", "--bits", "256", "--out", str(tmp_path / "key.json"), "-q"]) == 0
    code, out, err = _run(
        capsys,
        "encrypt",
        "phantom:10",
        "--key",
        tmp_path / "key.json",
        "--out",
        tmp_path / "v.zarr",
        "--brick",
        "5",
        "--vector-dims",
        "3",
        "--gradient",
        "-q",
    )
    assert code == 0, err
    code, out, _ = _run(capsys, "info", tmp_path / "v.zarr")
    assert code == 0 and "gradient[3]" in out
    key = hevr.load_key(tmp_path / "key.json")
    ev = hevr.open_volume(tmp_path / "v.zarr")
    vol = hevr.phantom(10)
    code, _, err = _run(
        capsys,
        "render",
        tmp_path / "v.zarr",
        "--out",
        tmp_path / "g.hevr",
        "--tf",
        TF,
        "--gradient",
        "--size",
        "9x8",
        "--azimuth",
        "20",
        "--keep-sums",
        tmp_path / "g.hevrsums",
        "-q",
    )
    assert code == 0, err
    cam = hevr.Camera.orbit(ev, azimuth=20, width=9, height=8)
    ref = hevr.render_plain(vol, cam, mode="tf", nodes=NODES, vector_dims=3, gradient=True)
    got = hevr.load_image(tmp_path / "g.hevr").decrypt(key, nodes=NODES)
    assert (np.abs(got - ref) <= hevr.error_bound(ev, cam, mode="tf", nodes=NODES, gradient=True)).all()
    code, _, err = _run(
        capsys,
        "recolour",
        tmp_path / "g.hevrsums",
        "--out",
        tmp_path / "r.hevr",
        "--density",
        "0.5",
        "--gradient",
        "-q",
    )
    assert code == 0, err
    ref = hevr.render_plain(vol, cam, mode="emphasize", density=0.5, vector_dims=3, gradient=True)
    got = hevr.load_image(tmp_path / "r.hevr").decrypt(key, density=0.5)
    assert (np.abs(got - ref) <= hevr.error_bound(ev, cam, mode="emphasize", density=0.5, gradient=True)).all()
    code, _, err = _run(
        capsys,
        "slice",
        tmp_path / "v.zarr",
        "--out",
        tmp_path / "s.hevr",
        "--axial",
        "5",
        "--density",
        "0.3",
        "--gradient",
        "-q",
    )
    assert code == 0, err
    plane = hevr.Plane.axial(ev, 5)
    ref = hevr.render_slice_plain(vol, plane, mode="emphasize", density=0.3, vector_dims=3, gradient=True)
    got = hevr.load_image(tmp_path / "s.hevr").decrypt(key, density=0.3)
    assert (np.abs(got - ref) <= hevr.error_bound(ev, plane, mode="emphasize", density=0.3, gradient=True)).all()
    # mistakes
    for argv, word in [
        (
            ["encrypt", "phantom:6", "--key", tmp_path / "key.json", "--out", tmp_path / "x.zarr", "--gradient"],
            "--gradient",
        ),
        (["render", tmp_path / "v.zarr", "--out", tmp_path / "x.hevr", "--gradient"], "--gradient"),
        (["recolour", tmp_path / "g.hevrsums", "--out", tmp_path / "x.hevr", "--tf", TF], "--gradient"),
    ]:
        code, _, err = _run(capsys, *argv)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith(f"hevr: error: {word}"), err
    assert (
        main(
            [
                "encrypt",
                "phantom:6",
                "--key",
                str(tmp_path / "key.json"),
                "--out",
                str(tmp_path / "n.zarr"),
                "--vector-dims",
                "2",
                "-q",
            ]
        )
        == 0
    )
    code, _, err = _run(capsys, "render", tmp_path / "n.zarr", "--out", tmp_path / "x.hevr", "--tf", TF, "--gradient")
    assert code == 2 and err.startswith("hevr: error: --gradient: expected a store encrypted with"), err
