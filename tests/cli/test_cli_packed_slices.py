"""``hevr slice`` on a packed store: decrypted in process with --key into a PNG or .npy, and the
refusals (other planes, options that do not apply, no key, a .hevr output) before any work."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def packed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli-packed-slices")
    key, store = tmp / "key.json", tmp / "p.zarr"
    assert main(["keygen", "--bits", "256", "--out", str(key)]) == 0
    assert (
        main(["encrypt", "phantom:12", "--key", str(key), "--out", str(store), "--layout", "packed", "--brick", "4"])
        == 0
    )
    return key, store


def test_slices_decrypted_in_process(packed, tmp_path, capsys):
    key, store = packed
    priv = hevr.load_key(key)
    vol = hevr.phantom(12)
    ev = hevr.open_volume(store)
    npy = tmp_path / "cor.npy"
    code, out, _ = run(
        capsys,
        "slice",
        store,
        "--out",
        npy,
        "--coronal",
        "5.5",
        "--sampling",
        "trilinear",
        "--key",
        key,
        "--no-verify",
        "--quiet",
    )
    assert code == 0, out
    assert "containing the packing axis z" in out and "verified" not in out and "wrote" in out
    arr = np.load(npy)
    plane = hevr.Plane.coronal(ev, 5.5)
    ref = hevr.render_slice_plain(vol, plane, sampling="trilinear", spacing=ev.spacing)
    assert arr.shape == ref.shape and ref.max() > 0
    assert (np.abs(arr - ref) <= hevr.error_bound(ev, plane, sampling="trilinear")).all()
    png = tmp_path / "ax.png"
    code, out, _ = run(capsys, "slice", store, "--out", png, "--axial", "4", "--key", key, "--quiet")
    assert code == 0 and "perpendicular to the packing axis z" in out
    assert f"verified: the slice's values are the store {ev.meta.store_id}'s" in out  # tags by default
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code, _, err = run(capsys, "slice", store, "--out", png, "--axial", "4", "--key", key, "--quiet")
    assert code == 2 and "--force" in err  # never over an existing file
    assert hevr.render_slice(ev, hevr.Plane.axial(ev, 4), progress=False, verify=False).decrypt(priv).max() > 0


@pytest.mark.parametrize(
    "extra, where, needle",
    [
        (["--oblique", ":1,0,1"], "--oblique", "perpendicular to the packing axis z or containing its direction"),
        (["--axial", "3", "--mode", "emphasize", "--density", "0.5"], "--mode", "xray"),
        (["--axial", "3", "--finish", "server"], "--finish server", "does not apply"),
        (["--axial", "3", "--no-pack"], "--no-pack", "does not apply"),
    ],
)
def test_refusals(packed, tmp_path, capsys, extra, where, needle):
    key, store = packed
    out = tmp_path / "x.png"
    code, _, err = run(capsys, "slice", store, "--out", out, "--key", key, "--quiet", *extra)
    assert code == 2 and where in err and needle in err, err
    assert not out.exists()


def test_verify_pins_the_store(packed, tmp_path, capsys):
    key, store = packed
    out = tmp_path / "v.png"
    code, _, err = run(
        capsys, "slice", store, "--out", out, "--key", key, "--quiet", "--axial", "3", "--verify", "0123456789abcdef"
    )
    assert code != 0 and "0123456789abcdef" in err and not out.exists()
    sid = hevr.open_volume(store).meta.store_id
    code, text, _ = run(capsys, "slice", store, "--out", out, "--key", key, "--quiet", "--axial", "3", "--verify", sid)
    assert code == 0 and "verified:" in text and out.exists()


def test_needs_key_and_an_image_file(packed, tmp_path, capsys):
    key, store = packed
    code, _, err = run(capsys, "slice", store, "--out", tmp_path / "a.png", "--axial", "3", "--quiet")
    assert code == 2 and "--key" in err and "decrypted in this process" in err
    code, _, err = run(capsys, "slice", store, "--out", tmp_path / "a.hevr", "--axial", "3", "--key", key, "--quiet")
    assert code == 2 and "--out" in err and ".png or .npy" in err
    assert not (tmp_path / "a.png").exists() and not (tmp_path / "a.hevr").exists()
