"""``hevr encrypt --layout packed``, ``hevr info`` of a packed store, ``hevr render`` / ``decrypt`` /
``info`` of packed frames, and the options and commands that refuse one."""

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


def test_encrypt_packed_info_and_refusals(tmp_path, capsys):
    key, store = tmp_path / "key.json", tmp_path / "p.zarr"
    assert run(capsys, "keygen", "--bits", "256", "--out", key)[0] == 0
    code, out, _ = run(
        capsys,
        "encrypt",
        "phantom:12",
        "--key",
        key,
        "--out",
        store,
        "--layout",
        "packed",
        "--pack-axis",
        "x",
        "--brick",
        "4",
        "--verifiable",
    )
    assert code == 0 and "packed:" in out and "along x" in out and "not verified yet" not in out
    assert "frames rendered with --key KEY are verified" in out
    ev = hevr.open_volume(store)
    assert ev.layout == "packed" and ev.packing.axis == 2 and ev.meta.tags
    priv = hevr.load_key(key)
    c = hevr.Camera.orbit(ev, azimuth=0, elevation=20, width=10, height=9, parallel=True)  # around x
    img = hevr.render(ev, c, progress=False, verify=False)
    ref = hevr.render_plain(hevr.phantom(12), c, slices="x")  # the reference of a store packed along x
    assert (np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(ev, c)).all()
    code, out, _ = run(capsys, "info", store)
    assert code == 0 and "packed:" in out and "voxels per ciphertext along x" in out
    code, out, err = run(capsys, "render", store, "--out", tmp_path / "f.hevr", "--size", "10x9", "--key", key, "-q")
    assert code == 0, err
    assert "anterior view (the packed store's default)" in out and "verified: the frame is the packed X-ray" in out
    code, _, err = run(capsys, "pyramid", store)
    assert code != 0 and "packed store" in err
    code, _, err = run(capsys, "encrypt", "phantom:12", "--key", key, "--out", tmp_path / "v.zarr", "--pack-axis", "z")
    assert code == 2 and "--pack-axis" in err and not (tmp_path / "v.zarr").exists()


@pytest.fixture(scope="module")
def packed_store(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli-packed")
    key, store = d / "key.json", d / "z.zarr"
    assert main(["keygen", "--bits", "256", "--out", str(key)]) == 0
    assert (
        main(
            [
                "encrypt",
                "phantom:12",
                "--key",
                str(key),
                "--out",
                str(store),
                "--layout",
                "packed",
                "--brick",
                "4",
                "-q",
            ]
        )
        == 0
    )  # verifiable by default: the owner's private key
    return key, store


def test_render_decrypt_info_packed_frame(packed_store, tmp_path, capsys):
    key, store = packed_store
    ev, priv = hevr.open_volume(store), hevr.load_key(key)
    assert ev.meta.tags and ev.packing.axis == 0
    frame = tmp_path / "x.hevr"
    code, out, err = run(
        capsys,
        "render",
        store,
        "--out",
        frame,
        "--key",
        key,
        "--size",
        "11x10",
        "--sampling",
        "trilinear",
        "--azimuth",
        "25",
        "--view",
        "anterior",
        "-q",
    )
    assert code == 0, err
    assert "verified: the frame is the packed X-ray of store " + ev.meta.store_id in out
    assert "stamped with the key holder's MAC" in out and f"hevr decrypt {frame}" in out
    assert frame.read_bytes().startswith(b"HEVRIMGP\x01")
    code, out, err = run(capsys, "info", frame)
    assert code == 0, err
    assert (
        "encrypted packed frame" in out
        and f"with the key holder's stamp, saved as {frame.resolve()}" in out
        and "view key" in out
    )
    assert "W×H = 11×10 px" in out and "trilinear" in out
    png, npy = tmp_path / "x.png", tmp_path / "x.npy"
    code, out, err = run(
        capsys, "decrypt", frame, "--key", key, "--out", png, "--npy", npy, "--require-verified", ev.meta.store_id
    )
    assert code == 0, err
    assert "verified: the frame is the packed X-ray" in out and png.is_file()
    arr = np.load(npy)
    cam = hevr.Camera.orbit(ev, view="anterior", azimuth=25, width=11, height=10, parallel=True)
    ref = hevr.render_plain(hevr.phantom(12), cam, sampling="trilinear", slices=True)
    assert arr.shape == (10, 11) and (np.abs(arr - ref) <= hevr.error_bound(ev, cam, sampling="trilinear")).all()
    assert np.array_equal(arr, hevr.load_image(frame).decrypt(priv))
    # colouring a packed X-ray: refused, one line naming the option
    code, _, err = run(capsys, "decrypt", frame, "--key", key, "--out", tmp_path / "c.png", "--tf", "0.5:red")
    assert code == 2 and err.count("\n") == 1 and "--tf" in err and "packed" in err
    # a stamped frame in another frame's place: not "verified" for it; with --require-verified exit 1, no PNG
    frame.rename(tmp_path / "y.hevr")
    code, out, err = run(capsys, "decrypt", tmp_path / "y.hevr", "--key", key, "--out", tmp_path / "y.png")
    assert code == 0 and "NOT verified for" in out and "--expect-view" in out, out  # an image, not "verified"
    code, _, err = run(
        capsys, "decrypt", tmp_path / "y.hevr", "--key", key, "--out", tmp_path / "z.png", "--require-verified"
    )
    assert code == 1 and f"saved this verified frame as {frame.resolve()}" in err and not (tmp_path / "z.png").exists()


def test_unverified_packed_frame(packed_store, tmp_path, capsys):
    key, store = packed_store
    frame = tmp_path / "u.hevr"
    code, out, err = run(capsys, "render", store, "--out", frame, "--size", "8", "-q")  # no key: not verified
    assert code == 0, err
    assert "not verified: no --key" in err and "verified: the frame" not in out
    code, out, _ = run(capsys, "info", frame)
    assert "no (no check against the store's tags" in out
    code, _, err = run(capsys, "decrypt", frame, "--key", key, "--out", tmp_path / "u.png", "--require-verified")
    assert code == 1 and "not verified" in err and not (tmp_path / "u.png").exists()
    code, out, err = run(capsys, "decrypt", frame, "--key", key, "--out", tmp_path / "u.png")
    assert code == 0 and "not verified" in out and (tmp_path / "u.png").is_file()


@pytest.mark.parametrize(
    "opts, named",
    [
        (["--mode", "emphasize", "--density", "0.5"], "--mode emphasize"),
        (["--tf", "0.5:red"], "--tf"),
        (["--step", "2"], "--step"),
        (["--finish", "server"], "--finish server"),
        (["--view-angle", "20"], "--view-angle"),
        (["--keep-sums", "{d}/s.hevrsums"], "--keep-sums"),
        (["--no-pack"], "--no-pack"),
        (["--gradient"], "--gradient"),  # an X-ray has no gradient modulation
        (["--view", "superior"], "--view"),  # along the packing axis z
        (["--azimuth", "0"], "--azimuth"),  # the plain orbit at 0 looks along z
        (["--view", "anterior", "--elevation", "60"], "--view/--elevation"),
    ],
)
def test_packed_render_refusals(packed_store, tmp_path, capsys, opts, named):
    key, store = packed_store
    opts = [o.replace("{d}", str(tmp_path)) for o in opts]
    code, _, err = run(capsys, "render", store, "--out", tmp_path / "f.hevr", "--size", "8", *opts)
    lines = [x for x in err.splitlines() if not x.startswith("hevr: warning: --view")]  # (a phantom: no RAS frame)
    assert code == 2 and len(lines) == 1 and lines[0].startswith(f"hevr: error: {named}"), err
    assert not (tmp_path / "f.hevr").exists()


def test_encrypt_verifiable_pair(tmp_path, capsys):
    key = tmp_path / "key.json"
    assert run(capsys, "keygen", "--bits", "256", "--out", key)[0] == 0
    # a new key's policy: every store carries tags, per-voxel ones too, and --no-verifiable is refused
    code, out, _ = run(capsys, "encrypt", "phantom:8", "--key", key, "--out", tmp_path / "d.zarr", "--brick", "4", "-q")
    assert code == 0 and hevr.open_volume(tmp_path / "d.zarr").meta.tags
    code, out, err = run(
        capsys,
        "encrypt",
        "phantom:8",
        "--key",
        key,
        "--out",
        tmp_path / "n.zarr",
        "--layout",
        "packed",
        "--brick",
        "4",
        "--no-verifiable",
        "-q",
    )
    assert code == 2 and "require_tags" in err and not (tmp_path / "n.zarr").exists(), err
    assert run(capsys, "key-policy", key, "--no-require-tags")[0] == 0  # a key without the policy
    code, out, _ = run(
        capsys,
        "encrypt",
        "phantom:8",
        "--key",
        key,
        "--out",
        tmp_path / "n.zarr",
        "--layout",
        "packed",
        "--brick",
        "4",
        "--no-verifiable",
        "-q",
    )
    assert code == 0 and "not verifiable: no tags" in out and not hevr.open_volume(tmp_path / "n.zarr").meta.tags
    code, out, _ = run(
        capsys, "encrypt", "phantom:8", "--key", key, "--out", tmp_path / "v.zarr", "--brick", "4", "--verifiable", "-q"
    )
    assert code == 0 and hevr.open_volume(tmp_path / "v.zarr").meta.tags  # a per-voxel store: on request
    code, out, _ = run(capsys, "encrypt", "phantom:8", "--key", key, "--out", tmp_path / "e.zarr", "--brick", "4", "-q")
    assert code == 0 and not hevr.open_volume(tmp_path / "e.zarr").meta.tags  # the library's default without it


def test_demo_packed_store(tmp_path, capsys):
    """The demo's packed store: smaller, its frame verified and within the error bound of its slice
    reference, saved stamped; no repeated 'not verified' warning; --no-packed leaves it out."""
    import json

    out_dir = tmp_path / "demo"
    code, out, err = run(
        capsys, "demo", "--out", out_dir, "--size", "8", "--image", "10x10", "--bits", "256", "--workers", "1", "-q"
    )
    assert code == 0, err
    assert "not verified" not in err and out.count("not verified: the per-voxel demo store has no tags") == 1
    packed = json.loads((out_dir / "summary.json").read_text())["packed"]
    assert packed["verified"] and packed["within_bound"] and packed["slots"] > 1
    assert packed["store_bytes"] < packed["voxel_store_bytes"] and packed["frame_s"] > 0 and packed["voxel_frame_s"] > 0
    assert "parallel X-ray frame s" in (out_dir / "report.md").read_text() and "packed (" in out
    img = hevr.load_image(out_dir / "xray-packed.hevr")
    priv = hevr.load_key(out_dir / "demo-key.json")
    assert img.stamp is not None and img.decrypt(priv, require_verified=True).shape == (10, 10)
    assert (out_dir / "xray-packed.png").is_file() and hevr.open_volume(out_dir / "volume-packed.zarr").meta.tags
    bare = tmp_path / "bare"
    code, out, err = run(
        capsys,
        "demo",
        "--out",
        bare,
        "--size",
        "6",
        "--image",
        "6x6",
        "--bits",
        "256",
        "--workers",
        "1",
        "-q",
        "--no-packed",
    )
    assert code == 0, err
    assert (
        "packed" not in json.loads((bare / "summary.json").read_text()) and not (bare / "volume-packed.zarr").exists()
    )


def test_packed_colour_frames_on_the_command_line(tmp_path, capsys):
    """hevr render --tf / --density [--gradient] on a packed store with the vector (and gradient)
    channel: a verified, stamped colour frame file; hevr decrypt colours it (the colouring stays
    here); hevr info describes it; decrypt without a colouring is refused naming the options."""
    key, store = tmp_path / "k.json", tmp_path / "c.zarr"
    assert main(["keygen", "--bits", "256", "--out", str(key)]) == 0
    assert (
        main(
            [
                "encrypt",
                "phantom:12",
                "--key",
                str(key),
                "--out",
                str(store),
                "--layout",
                "packed",
                "--vector-dims",
                "3",
                "--gradient",
                "--brick",
                "4",
                "-q",
            ]
        )
        == 0
    )
    capsys.readouterr()
    priv, ev = hevr.load_key(key), hevr.open_volume(store)
    for extra in (["--tf", "0.3:red,0.8:white"], ["--density", "0.5", "--gradient"]):
        frame = tmp_path / "f.hevr"
        code, out, err = run(
            capsys, "render", store, "--out", frame, "--key", key, "--size", "12x10", "-q", "--force", *extra
        )
        assert code == 0, err
        assert (
            "verified: the frame is the packed" in out
            and "decrypt it with:" in out
            and f"{extra[0]} " in out.split("decrypt it with:")[1]
        )
        png = tmp_path / "f.png"
        code, out, err = run(
            capsys,
            "decrypt",
            frame,
            "--key",
            key,
            "--out",
            png,
            "--npy",
            tmp_path / "f.npy",
            "--force",
            "--require-verified",
            *extra[:2],
        )
        assert code == 0 and "coloured on this machine" in out, err
        cam = hevr.Camera.orbit(ev, view="anterior", width=12, height=10, parallel=True)
        kw = (
            {"mode": "tf", "nodes": [(0.3, "red"), (0.8, "white")]}
            if extra[0] == "--tf"
            else {"mode": "emphasize", "density": 0.5, "gradient": True}
        )
        want = hevr.render(ev, cam, progress=False, verify=False, **kw).decrypt(priv)
        np.testing.assert_allclose(np.load(tmp_path / "f.npy"), want, rtol=0, atol=1e-12)
        code, out, _ = run(capsys, "info", frame)
        assert code == 0 and "components of a packed store, coloured at decryption" in out
    code, _, err = run(capsys, "decrypt", frame, "--key", key, "--out", tmp_path / "x.png")
    assert code == 2 and "--tf, --density" in err and not (tmp_path / "x.png").exists()
