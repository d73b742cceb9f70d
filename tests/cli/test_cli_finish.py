"""``--finish client`` (the default) on the command line: ``hevr render --tf`` writes the ray sums
only and prints the ``hevr decrypt ... --tf`` command that colours them; ``hevr decrypt --tf /
--density`` colours a client frame (any other colouring too, no server); ``--finish server``
frames decrypt as before and take no colouring; mistakes exit 2 in one line naming the option.

256-bit keys and tiny phantoms: fast, NOT secure.
"""

from __future__ import annotations

import shlex

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

TF = "0.279:#0000ff,0.797:red"
NODES = [(0.279, "#0000ff"), (0.797, "red")]
VIEW = ["--size", "11x9", "--azimuth", "30", "--elevation", "10", "-q"]


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _ok(capsys, *argv) -> str:
    code, out, err = _run(capsys, *argv)
    assert code == 0, err
    return out


def _fails(capsys, *argv) -> str:
    code, out, err = _run(capsys, *argv)
    assert code == 2, (code, out, err)
    assert err.count("\n") == 1 and err.startswith("hevr: error: "), err
    return err[len("hevr: error: ") :]


@pytest.fixture(scope="module")
def store(cli_store):
    return cli_store("finish", brick=5)


def _reference(d, finish="client", **kw):
    """render_plain of the test view, and error_bound of a render finished on ``finish``."""
    ev = hevr.open_volume(d / "vol.zarr")
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=10, width=11, height=9)
    ref = hevr.render_plain(hevr.phantom(10), cam, value_range=ev.value_range, vector_dims=3, **kw)
    return ref, hevr.error_bound(ev, cam, finish=finish, **kw)


def _decrypt_line(out: str) -> list[str]:
    line = next(ln for ln in out.splitlines() if ln.startswith("decrypt it with: "))
    return shlex.split(line[len("decrypt it with: ") :])


def test_render_tf_then_decrypt_tf_matches_the_plaintext(store, tmp_path, capsys):
    d = store
    out = _ok(capsys, "render", d / "vol.zarr", "--out", tmp_path / "tf.hevr", "--tf", TF, *VIEW)
    assert "applied at decryption" in out and "not the transfer function" in out
    argv = _decrypt_line(out)  # the exact command, key and PNG names aside
    assert argv[:2] == ["hevr", "decrypt"] and argv[argv.index("--tf") + 1] == "0.279:#0000ff,0.797:#ff0000"
    argv = argv[2:]
    argv[argv.index("--key") + 1] = str(d / "key.json")
    out = _ok(capsys, "decrypt", *argv, "--npy", tmp_path / "tf.npy")
    assert "coloured on this machine" in out and "rgb" in out
    got = np.load(tmp_path / "tf.npy")
    ref, bound = _reference(d, mode="tf", nodes=NODES)
    assert got.shape == ref.shape and (np.abs(got - ref) <= bound).all() and ref.max() > 0
    assert (tmp_path / "tf.png").stat().st_size > 0
    # the same frame, re-coloured at decryption: an emphasis and another transfer function
    _ok(
        capsys,
        "decrypt",
        tmp_path / "tf.hevr",
        "--key",
        d / "key.json",
        "--density",
        "0.653",
        "--out",
        tmp_path / "e.png",
        "--npy",
        tmp_path / "e.npy",
        "-q",
    )
    ref, bound = _reference(d, mode="emphasize", density=0.653)
    got = np.load(tmp_path / "e.npy")
    assert got.shape == ref.shape and (np.abs(got - ref) <= bound).all()
    _ok(
        capsys,
        "decrypt",
        tmp_path / "tf.hevr",
        "--key",
        d / "key.json",
        "--mode",
        "tf",
        "--out",
        tmp_path / "p.png",
        "--npy",
        tmp_path / "p.npy",
        "-q",
    )  # --mode tf alone: the paper's first TF
    ref, bound = _reference(d, mode="tf", nodes=list(hevr.paper.PAPER_TF1))
    assert (np.abs(np.load(tmp_path / "p.npy") - ref) <= bound).all()


def test_the_frame_file_holds_no_colouring(store, tmp_path, capsys):
    d = store
    out = _ok(
        capsys, "render", d / "vol.zarr", "--out", tmp_path / "tf.hevr", "--tf", "0.2345:#123456,0.8765:#abcdef", *VIEW
    )
    assert "--tf '0.2345:#123456,0.8765:#abcdef'" in out
    out = _ok(capsys, "render", d / "vol.zarr", "--out", tmp_path / "e.hevr", "--density", "0.6543", *VIEW)
    assert "--density 0.6543" in out and "not the density" in out
    for name, secrets in (("tf.hevr", ("123456", "abcdef", "0.2345", "0.8765")), ("e.hevr", ("0.6543",))):
        blob = (tmp_path / name).read_bytes()
        assert not any(s.encode() in blob for s in secrets), name
        img = hevr.load_image(tmp_path / name)
        assert img.finish == "client" and "nodes" not in img.info and "density" not in img.info
        assert img.colouring is None
    out = _ok(capsys, "info", tmp_path / "tf.hevr")
    assert "finish:      client: the ray sums of the vector channel" in out and "components:  3 per pixel" in out
    assert "transfer fn" not in out and "123456" not in out


def test_a_vector_client_frame_needs_tf_or_density(store, tmp_path, capsys):
    d = store
    _ok(capsys, "render", d / "vol.zarr", "--out", tmp_path / "tf.hevr", "--tf", TF, *VIEW)
    key = d / "key.json"
    err = _fails(capsys, "decrypt", tmp_path / "tf.hevr", "--key", key, "--out", tmp_path / "x.png")
    assert err.startswith("--tf, --density: expected one of them to colour") and "vector channel" in err
    err = _fails(capsys, "decrypt", tmp_path / "tf.hevr", "--key", key, "--mode", "xray")
    assert err.startswith("--mode xray: expected --mode emphasize or tf")
    err = _fails(capsys, "decrypt", tmp_path / "tf.hevr", "--key", key, "--mode", "emphasize")
    assert err.startswith("--mode emphasize: expected --density D")
    err = _fails(capsys, "decrypt", tmp_path / "tf.hevr", "--key", key, "--tf", "ct-bone")
    assert err.startswith("--tf ct-bone: a preset needs the store's value range")
    err = _fails(capsys, "decrypt", tmp_path / "tf.hevr", "--key", key, "--tf", TF, "--value-range", "0,255")
    assert err.startswith("--value-range: only applies to a --tf preset")
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "tf.png").exists()
    # an X-ray client frame decrypts as it is, and takes no colouring
    _ok(capsys, "render", d / "vol.zarr", "--out", tmp_path / "x.hevr", *VIEW)
    err = _fails(capsys, "decrypt", tmp_path / "x.hevr", "--key", key, "--density", "0.5")
    assert err.startswith("--density: expected no colouring for")
    _ok(capsys, "decrypt", tmp_path / "x.hevr", "--key", key, "--npy", tmp_path / "x.npy", "-q")
    ref, bound = _reference(d, mode="xray")
    assert (np.abs(np.load(tmp_path / "x.npy") - ref) <= bound).all()


def test_finish_server_round_trip(store, tmp_path, capsys):
    d = store
    out = _ok(capsys, "render", d / "vol.zarr", "--out", tmp_path / "s.hevr", "--tf", TF, "--finish", "server", *VIEW)
    assert "applied at decryption" not in out and "--tf" not in _decrypt_line(out)
    img = hevr.load_image(tmp_path / "s.hevr")
    assert img.finish == "server" and img.info["nodes"]
    _ok(capsys, "decrypt", tmp_path / "s.hevr", "--key", d / "key.json", "--npy", tmp_path / "s.npy", "-q")
    ref, bound = _reference(d, "server", mode="tf", nodes=NODES)
    assert (np.abs(np.load(tmp_path / "s.npy") - ref) <= bound).all()
    err = _fails(
        capsys, "decrypt", tmp_path / "s.hevr", "--key", d / "key.json", "--tf", TF, "--out", tmp_path / "t.png"
    )
    assert err.startswith("--tf: only for a frame finished on the client") and "--finish client" in err
    out = _ok(capsys, "info", tmp_path / "s.hevr")
    assert "finish:      server" in out and "transfer fn: 0.279:#0000ff,0.797:#ff0000" in out
    err = _fails(capsys, "render", d / "vol.zarr", "--out", tmp_path / "y.hevr", "--finish", "paper")
    assert err.startswith("argument --finish: invalid choice")


def test_recolour_and_slice_print_the_decrypt_command(store, tmp_path, capsys):
    d = store
    _ok(
        capsys,
        "render",
        d / "vol.zarr",
        "--out",
        tmp_path / "tf.hevr",
        "--tf",
        TF,
        "--keep-sums",
        tmp_path / "v.hevrsums",
        *VIEW,
    )
    out = _ok(capsys, "recolour", tmp_path / "v.hevrsums", "--out", tmp_path / "r.hevr", "--density", "0.4", "-q")
    assert "packed for colouring at decryption" in out and _decrypt_line(out)[-2:] == ["--density", "0.4"]
    out = _ok(
        capsys,
        "recolour",
        tmp_path / "v.hevrsums",
        "--out",
        tmp_path / "s.hevr",
        "--density",
        "0.4",
        "--finish",
        "server",
        "-q",
    )
    assert "re-coloured in" in out and "--density" not in _decrypt_line(out)
    _ok(capsys, "decrypt", tmp_path / "s.hevr", "--key", d / "key.json", "--npy", tmp_path / "s.npy", "-q")
    _ok(
        capsys,
        "decrypt",
        tmp_path / "r.hevr",
        "--key",
        d / "key.json",
        "--density",
        "0.4",
        "--npy",
        tmp_path / "r.npy",
        "-q",
    )
    ref, bound = _reference(d, mode="emphasize", density=0.4)
    assert (np.abs(np.load(tmp_path / "r.npy") - ref) <= bound).all()
    ref, bound = _reference(d, "server", mode="emphasize", density=0.4)
    assert (np.abs(np.load(tmp_path / "s.npy") - ref) <= bound).all()
    out = _ok(capsys, "slice", d / "vol.zarr", "--out", tmp_path / "sl.hevr", "--axial", "4", "--tf", TF, "-q")
    assert _decrypt_line(out)[-2:] == ["--tf", "0.279:#0000ff,0.797:#ff0000"]
    assert "finish" in _ok(capsys, "slice", "--help")


def test_slice_finish_server(store, tmp_path, capsys):
    """``hevr slice --finish server`` passes through to hevr.render_slice."""
    d = store
    argv = [
        "slice",
        d / "vol.zarr",
        "--out",
        tmp_path / "s.hevr",
        "--axial",
        "4",
        "--density",
        "0.5",
        "--finish",
        "server",
    ]
    out = _ok(capsys, *argv, "-q")
    assert "--density" not in _decrypt_line(out)
    assert hevr.load_image(tmp_path / "s.hevr").finish == "server"
    _ok(capsys, "decrypt", tmp_path / "s.hevr", "--key", d / "key.json", "-q")
