"""``hevr slice``: the written frame decrypts to the plaintext reference; bad options exit 2 naming
the option.

256-bit keys and a tiny phantom: fast, NOT secure.
"""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.rendering import Plane, render_slice_plain

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _ok(capsys, *argv) -> str:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def _fails(capsys, *argv) -> str:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 2, (code, out, err)
    assert err.count("\n") == 1, err  # one line
    return err


@pytest.fixture(scope="module")
def store(cli_store):
    return cli_store("slice")


def _decrypt(store, frame, density=None, nodes=None, **_):
    return hevr.load_image(frame).decrypt(hevr.load_key(store / "key.json"), density=density, nodes=nodes)


def test_axial_slice_is_the_layer(store, tmp_path, capsys):
    out = _ok(capsys, "slice", store / "vol.zarr", "--out", tmp_path / "a.hevr", "--axial", "4", "-q")
    assert "axial, k = 4" in out and "W×H = 10×10" in out and "x×y×z = 10×10×10" in out
    assert np.abs(_decrypt(store, tmp_path / "a.hevr") - hevr.phantom(10)[4]).max() <= 1e-9
    out = _ok(capsys, "decrypt", tmp_path / "a.hevr", "--key", store / "key.json", "--out", tmp_path / "a.png", "-q")
    assert (tmp_path / "a.png").stat().st_size > 0
    out = _ok(capsys, "info", tmp_path / "a.hevr")
    assert "plane:" in out and "slab 1" in out


@pytest.mark.parametrize(
    "argv, plane, kw",
    [
        (
            ["--coronal", "6.5", "--size", "14x12", "--sampling", "trilinear"],
            lambda ev: Plane.coronal(ev, 6.5, width=14, height=12),
            {"sampling": "trilinear"},
        ),
        (
            ["--sagittal", "2", "--pixel-spacing", "0.7", "--slab", "3", "--slab-step", "0.5"],
            lambda ev: Plane.sagittal(ev, 2, pixel_spacing=0.7, slab=3, slab_step=0.5),
            {},
        ),
        (
            ["--oblique", ":1,2,2", "--size", "12x11", "--tf", "0.2:red,0.8:blue"],
            lambda ev: Plane.oblique(ev, None, (1, 2, 2), width=12, height=11),
            {"mode": "tf", "nodes": [(0.2, "red"), (0.8, "blue")]},
        ),
        (
            ["--oblique", "4,4.5,5:0,-1,0.3", "--size", "9x9", "--density", "0.5", "--slab", "2"],
            lambda ev: Plane.oblique(ev, (4, 4.5, 5), (0, -1, 0.3), width=9, height=9, slab=2),
            {"mode": "emphasize", "density": 0.5},
        ),
    ],
)
def test_slices_match_the_reference(store, tmp_path, capsys, argv, plane, kw):
    out = _ok(capsys, "slice", store / "vol.zarr", "--out", tmp_path / "s.hevr", *argv, "-q")
    assert "wrote" in out and "decrypt it with" in out
    ev = hevr.open_volume(store / "vol.zarr")
    p = plane(ev)
    got = _decrypt(store, tmp_path / "s.hevr", **kw)
    ref = render_slice_plain(hevr.phantom(10), p, vector_dims=3, **kw)
    bound = hevr.error_bound(ev, p, **kw)
    assert got.shape == ref.shape and np.all(np.abs(got - ref) <= bound)
    assert np.count_nonzero(ref) > 10


@pytest.mark.parametrize(
    "argv, start",
    [
        (["--axial", "40"], "--axial: expected a position in [0, 9], got 40"),
        (["--coronal", "-1"], "--coronal: expected a position in [0, 9]"),
        (["--oblique", "1,2:0,0,1"], "argument --oblique: expected CX,CY,CZ:NX,NY,NZ"),
        (["--oblique", "1,2,3:0,0,0"], "argument --oblique: expected CX,CY,CZ:NX,NY,NZ"),
        (["--axial", "1", "--sagittal", "2"], "argument --sagittal: not allowed with argument --axial"),
        ([], "one of the arguments --axial --coronal --sagittal --oblique is required"),
        (["--axial", "1", "--size", "0x4"], "argument --size: expected WIDTHxHEIGHT"),
        (["--axial", "1", "--pixel-spacing", "0"], "argument --pixel-spacing: expected a positive number"),
        (["--axial", "1", "--slab", "0"], "argument --slab: expected a positive integer"),
        (["--axial", "1", "--slab", "70000"], "--slab: expected an integer in [1, 65536], got 70000"),
        (["--axial", "1", "--slab-step", "2"], "--slab-step: only applies to a thick slab"),
        (["--axial", "1", "--mode", "xray", "--tf", "0.5:red"], "--tf: only applies to --mode tf"),
        (["--axial", "1", "--mode", "emphasize"], "--mode emphasize: expected --density D"),
        (["--axial", "1", "--mode", "mip"], "argument --mode: invalid choice"),
    ],
)
def test_bad_options_exit_2_naming_the_option(store, tmp_path, capsys, argv, start):
    err = _fails(capsys, "slice", store / "vol.zarr", "--out", tmp_path / "x.hevr", *argv)
    assert err.startswith(f"hevr: error: {start}"), err
    assert not (tmp_path / "x.hevr").exists()


def test_bad_store_and_output(store, tmp_path, capsys):
    err = _fails(capsys, "slice", tmp_path / "none.zarr", "--out", tmp_path / "x.hevr", "--axial", "1")
    assert err.startswith("hevr: error: STORE:"), err
    err = _fails(capsys, "slice", store / "key.json", "--out", tmp_path / "x.hevr", "--axial", "1")
    assert err.startswith("hevr: error: STORE:"), err
    err = _fails(capsys, "slice", store / "vol.zarr", "--out", tmp_path, "--axial", "1")
    assert err.startswith("hevr: error: --out: expected a file name"), err


def test_help_lists_slice(capsys):
    assert main(["slice", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--oblique CX,CY,CZ:NX,NY,NZ" in out and "no MIP" in out


def test_slice_pngs_are_shown_the_radiological_way(tmp_path, capsys):
    """Issue 39, item 6: a coronal or sagittal PNG has superior at the top, an axial one anterior
    (raw array order put the head at the bottom); the banners say which convention."""
    from PIL import Image

    k, j, i = np.meshgrid(np.arange(6), np.arange(7), np.arange(8), indexing="ij")
    np.save(tmp_path / "v.npy", (100 * k + 10 * j + i).astype(np.int16))  # grows to superior, anterior, right
    key = tmp_path / "key.json"
    _ok(capsys, "keygen", "--bits", "256", "--out", key, "-q")
    _ok(capsys, "encrypt", tmp_path / "v.npy", "--key", key, "--out", tmp_path / "v.zarr", "--brick", "4", "-q")
    for opt, top, left in (
        ("--coronal", "superior", "the patient's right"),
        ("--sagittal", "superior", "anterior"),
        ("--axial", "anterior", "the patient's right"),
    ):
        out = _ok(capsys, "slice", tmp_path / "v.zarr", "--out", tmp_path / f"{opt[2:]}.hevr", opt, "3", "-q")
        assert f"radiological convention: {top} at the top, {left} on the left" in out
        out = _ok(capsys, "decrypt", tmp_path / f"{opt[2:]}.hevr", "--key", key, "--out", tmp_path / f"{opt[2:]}.png")
        assert f"{opt[2:]} slice, radiological convention: {top} at the top" in out
        png = np.asarray(Image.open(tmp_path / f"{opt[2:]}.png")).astype(float)
        assert png[0].mean() > png[-1].mean() + 20, (opt, png)  # the top row is superior / anterior
        assert png[:, 0].mean() > png[:, -1].mean(), (opt, png)  # the left column: the patient's right / anterior


def test_slice_banner_places_the_plane_in_the_scans_frame(tmp_path, capsys):
    """Issue 39, item 10: the banner said z = 2 for a scan whose voxel 0 lies at z = 30 mm."""
    np.arange(6 * 6 * 6, dtype=np.uint8).tofile(tmp_path / "v.raw")
    (tmp_path / "v.nhdr").write_text(
        "NRRD0004\ntype: uint8\ndimension: 3\nspace: right-anterior-superior\n"
        "sizes: 6 6 6\nspace directions: (1,0,0) (0,2,0) (0,0,1.5)\nkinds: domain domain "
        "domain\nendian: little\nencoding: raw\nspace origin: (10,20,30)\ndata file: v.raw\n"
    )
    key = tmp_path / "key.json"
    _ok(capsys, "keygen", "--bits", "256", "--out", key, "-q")
    _ok(capsys, "encrypt", tmp_path / "v.nhdr", "--key", key, "--out", tmp_path / "v.zarr", "-q")
    out = _ok(capsys, "slice", tmp_path / "v.zarr", "--out", tmp_path / "a.hevr", "--axial", "2", "-q")
    assert "axial, k = 2 (z = 3 from voxel 0, z = 33 mm in the scan's RAS+ frame)" in out, out
    out = _ok(capsys, "slice", tmp_path / "v.zarr", "--out", tmp_path / "c.hevr", "--coronal", "1", "-q")
    assert "coronal, j = 1 (y = 2 from voxel 0, y = 22 mm in the scan's RAS+ frame)" in out, out
