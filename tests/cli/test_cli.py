"""The ``hevr`` command line, end to end in a temporary folder (256-bit keys: fast, NOT secure)."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import hevr
from hevr.cli.main import main
from hevr.image.display import to_uint8

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

COMMANDS = ["keygen", "encrypt", "render", "decrypt", "info", "demo", "bench"]
AZ, EL, W, H = 25.0, 15.0, 20, 16


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def err_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """keygen -> encrypt phantom:12 (brick 5, 4-dim vector) -> renders -> decrypts, once per module."""
    d = tmp_path_factory.mktemp("cli")
    cap = {}

    def call(*argv):
        import contextlib
        import io

        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in argv])
        cap.setdefault(argv[0], (code, out.getvalue(), err.getvalue()))
        assert code == 0, (argv, out.getvalue(), err.getvalue())
        return out.getvalue(), err.getvalue()

    key = d / "key.json"
    call("keygen", "--bits", "256", "--out", key)
    call(
        "encrypt",
        "phantom:12",
        "--key",
        d / "key.pub.json",
        "--out",
        d / "vol.zarr",
        "--brick",
        "5",
        "--vector-dims",
        "4",
        "-q",
    )
    common = ["--azimuth", AZ, "--elevation", EL, "--size", f"{W}x{H}", "-q"]
    # a store made with the public key has no tags: the key holder (whose new key requires them) accepts it once
    call("render", d / "vol.zarr", "--out", d / "accept.hevr", "--key", key, "--trust-store", "--untagged", *common)
    call("render", d / "vol.zarr", "--out", d / "xray.hevr", "--mode", "xray", "--sampling", "nearest", *common)
    call("render", d / "vol.zarr", "--out", d / "tf.hevr", "--tf", "0.279:#0000ff,0.797:red", *common)
    call("decrypt", d / "xray.hevr", "--key", key, "--out", d / "xray.png", "--npy", d / "xray.npy")
    call("decrypt", d / "tf.hevr", "--key", key, "--out", d / "tf.png", "--tf", "0.279:#0000ff,0.797:red")
    return d, cap


def test_keygen_files_and_modes(work, capsys):
    d, cap = work
    code, out, err = cap["keygen"]
    key, pub_file = d / "key.json", d / "key.pub.json"
    assert stat.S_IMODE(key.stat().st_mode) == 0o600
    assert pub_file.exists()
    priv, pub = hevr.load_key(key), hevr.load_key(pub_file)
    assert isinstance(priv, hevr.PrivateKey) and isinstance(pub, hevr.PublicKey)
    assert pub.fingerprint in out and priv.fingerprint == pub.fingerprint
    assert str(priv.p) not in out and str(priv.q) not in out
    lines = err_lines(err)
    assert len(lines) == 1 and lines[0].startswith("hevr: warning:") and "256" in lines[0]
    # refuses to overwrite without --force, replaces with it
    code, out, err = run(capsys, "keygen", "--bits", "256", "--out", key)
    assert code == 2 and err_lines(err)[-1].startswith("hevr: error: --out:") and "--force" in err
    other = d / "other.json"
    assert run(capsys, "keygen", "--bits", "256", "--out", other, "-q")[0] == 0
    assert run(capsys, "keygen", "--bits", "256", "--out", other, "--force")[0] == 0
    assert hevr.load_key(d / "other.pub.json").fingerprint == hevr.load_key(other).fingerprint


def test_encrypt_reports_path(work, capsys):
    d, cap = work
    assert "public-key path" in cap["encrypt"][1]
    code, out, err = run(capsys, "encrypt", "phantom:6", "--key", d / "key.json", "--out", d / "small.zarr", "-q")
    assert code == 0 and "owner-side fast path" in out
    ev = hevr.open_volume(d / "small.zarr")
    assert ev.shape == (6, 6, 6) and ev.vector_dims is None
    # exists -> refused; --overwrite replaces it
    code, out, err = run(capsys, "encrypt", "phantom:6", "--key", d / "key.json", "--out", d / "small.zarr", "-q")
    assert code == 2 and "--overwrite" in err_lines(err)[-1]
    code, out, err = run(
        capsys,
        "encrypt",
        "phantom:6",
        "--key",
        d / "key.json",
        "--out",
        d / "small.zarr",
        "--overwrite",
        "--no-scalar",
        "--vector-dims",
        "3",
        "-q",
    )
    assert code == 0 and hevr.open_volume(d / "small.zarr").vector_dims == 3


@pytest.mark.parametrize(
    "name, mode, kw",
    [
        ("xray", "xray", {}),
        ("tf", "tf", {"nodes": [(0.279, "#0000ff"), (0.797, "red")]}),
    ],
)
def test_png_matches_plaintext_reference(work, name, mode, kw):
    d, _ = work
    vol = hevr.phantom(12)
    cam = hevr.Camera.orbit(vol.shape, azimuth=AZ, elevation=EL, width=W, height=H)
    ref = hevr.render_plain(vol, cam, mode=mode, sampling="nearest", value_range=(0, 255), vector_dims=4, **kw)
    png = np.asarray(Image.open(d / f"{name}.png"))
    assert png.shape == ref.shape
    diff = np.abs(png.astype(int) - to_uint8(ref).astype(int))
    assert diff.max() <= 1
    if name == "xray":
        assert np.allclose(np.load(d / "xray.npy"), ref, atol=1e-3)


def test_info_exits_non_zero_when_its_check_fails(work, capsys, tmp_path):
    d, _ = work
    bad = tmp_path / "bad.zarr"
    shutil.copytree(d / "vol.zarr", bad)
    chunk = next(p for p in sorted((bad / "scalar" / "c").rglob("*")) if p.is_file())
    chunk.write_bytes(chunk.read_bytes()[:-7])  # truncated: the chunk-size check fails
    code, out, err = run(capsys, "info", bad)
    assert code == 1, (out, err)
    assert "FAILED" in out and "encrypted volume store" in out  # the table is still printed
    assert run(capsys, "info", d / "vol.zarr")[0] == 0


def test_info_never_prints_secrets(work, capsys):
    d, _ = work
    priv = hevr.load_key(d / "key.json")
    fp = priv.fingerprint
    secrets = (str(priv.p), str(priv.q))
    for path, what in [
        (d / "vol.zarr", "store"),
        (d / "tf.hevr", "image"),
        (d / "key.pub.json", "public key"),
        (d / "key.json", "private key"),
    ]:
        code, out, err = run(capsys, "info", path)
        assert code == 0, err
        assert fp in out and what in out
        assert not any(s in out or s in err for s in secrets)
    out = run(capsys, "info", d / "vol.zarr")[1]
    assert "x×y×z = 12×12×12 voxels" in out and "27 bricks" in out and "vector[4]" in out and "complete:    True" in out
    out = run(capsys, "info", d / "tf.hevr")[1]
    assert "finish:      client" in out and "components:  4 per pixel" in out and "--tf" in out
    assert "exponent" in out and "ciphertexts" in out


@pytest.mark.parametrize("command", COMMANDS)
def test_help(command, capsys):
    code, out, err = run(capsys, command, "--help")
    assert code == 0 and f"hevr {command}" in out and "example" in out and err == ""


def _bad_cases(d: Path) -> list[tuple[list, int, str]]:
    return [
        (["keygen", "--bits", "1001", "--out", d / "k.json"], 2, "--bits"),
        (["keygen", "--bits", "abc"], 2, "--bits"),
        (["encrypt", "phantom:8", "--key", d / "missing.json", "--out", d / "x.zarr"], 2, "missing.json"),
        (["encrypt", d / "nothing.npy", "--key", d / "key.json", "--out", d / "x.zarr"], 2, "nothing.npy"),
        (["encrypt", d / "notes.txt", "--key", d / "key.json", "--out", d / "x.zarr"], 2, "extension"),
        (["encrypt", "phantom:8", "--key", d / "key.json", "--out", d / "x.zarr", "--brick", "0"], 2, "--brick"),
        (["render", d / "missing.zarr", "--out", d / "x.hevr"], 2, "missing.zarr"),
        (["render", d / "vol.zarr", "--out", d / "x.hevr", "--tf", "0.5:notacolour"], 2, "notacolour"),
        (["render", d / "vol.zarr", "--out", d / "x.hevr", "--tf", "1.5:red"], 2, "[0, 1]"),
        (["render", d / "vol.zarr", "--out", d / "x.hevr", "--size", "20by20"], 2, "--size"),
        (["render", d / "vol.zarr", "--out", d / "x.hevr", "--mode", "emphasize"], 2, "--density"),
        (["decrypt", d / "xray.hevr", "--key", d / "wrong.json", "--out", d / "x.png"], 2, "encrypted under key"),
        (["decrypt", d / "xray.hevr", "--key", d / "key.pub.json", "--out", d / "pub.png"], 2, "private key"),
        (["decrypt", d / "notes.txt", "--key", d / "key.json"], 2, "notes.txt"),
        (["info", d / "nothing-here"], 2, "nothing-here"),
        (["demo", "--image", "0x5"], 2, "--image"),
        (["bench", "--quick", "--paper"], 2, "not allowed"),
        (["frobnicate"], 2, "invalid choice"),
        ([], 2, "command"),
    ]


def test_errors_are_one_line(work, capsys):
    d, _ = work
    (d / "notes.txt").write_text("not a volume\n")
    assert run(capsys, "keygen", "--bits", "256", "--out", d / "wrong.json", "-q")[0] == 0
    for argv, code, needle in _bad_cases(d):
        got, out, err = run(capsys, *argv)
        lines = err_lines(err)
        assert got == code, (argv, got, err)
        assert len(lines) == 1 and lines[0].startswith("hevr: error:"), (argv, err)
        assert needle in lines[0], (argv, lines[0])
        assert "Traceback" not in err


def test_verbose_shows_traceback(work, capsys):
    d, _ = work
    code, out, err = run(capsys, "decrypt", d / "xray.hevr", "--key", d / "wrong.json", "--verbose", "--force")
    assert code == 2 and "Traceback" in err and "KeyMismatchError" in err
    assert err_lines(err)[-1].startswith("hevr: error:")


def test_mode_inference_and_tf_parsing():
    from hevr.cli.render_options import parse_tf, size_type

    assert parse_tf("0.279:#0000ff, 0.797:red") == [(0.279, (0.0, 0.0, 1.0)), (0.797, (1.0, 0.0, 0.0))]
    assert size_type("150x100") == (150, 100) and size_type("64") == (64, 64)
    with pytest.raises(hevr.ParameterError):
        parse_tf("0.5-red")


def test_demo_tiny(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    code, out, err = run(
        capsys, "demo", "--out", out_dir, "--size", "10", "--image", "12x12", "--bits", "256", "--workers", "1", "-q"
    )
    assert code == 0, err
    summary = json.loads((out_dir / "summary.json").read_text())
    names = [im["name"] for im in summary["images"]]
    assert names == [
        "xray-nearest",
        "xray-trilinear",
        "emphasize-0.331",
        "emphasize-0.653",
        "emphasize-0.781",
        "tf1",
        "tf2",
    ]
    for im in summary["images"]:
        assert im["within_bound"] and im["max_abs_error"] < 0.05
        for f in (im["png"], im["reference_png"], im["frame"]):
            assert (out_dir / f).is_file()
    assert (out_dir / "contact-sheet.png").is_file() and (out_dir / "report.md").is_file()
    assert {"keygen", "encrypt", "persist", "render tf2", "decrypt (all)"} <= set(summary["stages_s"])
    # open once, render many: every image that ran map tasks took its bricks from worker memory
    assert all(im["resident"] or im["reused_ray_sums"] for im in summary["images"])
    assert "max|err|" in out and "keygen" in out and "encrypt" in out
    assert stat.S_IMODE((out_dir / "demo-key.json").stat().st_mode) == 0o600
    # run again into the same folder: the demo replaces its own run (key included)
    code, out, err = run(
        capsys, "demo", "--out", out_dir, "--size", "6", "--image", "6x6", "--bits", "256", "--workers", "1", "-q"
    )
    assert code == 0, err


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
def test_bench_quick_threaded(capsys, tmp_path):
    code, out, err = run(capsys, "bench", "--quick", "--workers", "0", "-q", "--out", str(tmp_path), "--only", "t1")
    assert code == 0, err
    assert "t1.64 done" in out and (tmp_path / "RESULTS-quick.md").is_file()


def _hevr_exe() -> list[str]:
    exe = Path(sys.executable).with_name("hevr")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "hevr"]


def test_console_script_subprocess(work):
    d, _ = work
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    r = subprocess.run(
        _hevr_exe() + ["info", str(d / "key.pub.json")], capture_output=True, text=True, env=env, timeout=60
    )
    assert r.returncode == 0 and hevr.load_key(d / "key.pub.json").fingerprint in r.stdout
    r = subprocess.run(
        [sys.executable, "-m", "hevr", "render", str(d / "vol.zarr"), "--out", str(d / "y.hevr"), "--size", "10x10x10"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("hevr: error: argument --size")


def test_ct_xray_default_window_shows_the_object(tmp_path, capsys):
    """Issue 39, item 7: an X-ray of a CT-like volume (air -1000, a positive object) is windowed
    over its value range by default: the object brighter than the air around it, not black."""
    from PIL import Image

    vol = np.full((12, 12, 12), -1000, dtype=np.int16)
    vol[3:9, 4:8, 4:8] = 400  # the object: every ray through it averages above the air's rays
    np.save(tmp_path / "ct.npy", vol)
    key = tmp_path / "key.json"
    assert run(capsys, "keygen", "--bits", "256", "--out", key, "-q")[0] == 0
    assert (
        run(capsys, "encrypt", tmp_path / "ct.npy", "--key", key, "--out", tmp_path / "ct.zarr", "--brick", "6", "-q")[
            0
        ]
        == 0
    )
    assert (
        run(
            capsys,
            "render",
            tmp_path / "ct.zarr",
            "--out",
            tmp_path / "x.hevr",
            "--mode",
            "xray",
            "--size",
            "24x24",
            "-q",
        )[0]
        == 0
    )
    code, out, err = run(
        capsys, "decrypt", tmp_path / "x.hevr", "--key", key, "--out", tmp_path / "x.png", "--npy", tmp_path / "x.npy"
    )
    assert code == 0, err
    values = np.load(tmp_path / "x.npy")
    hits = hevr.load_image(tmp_path / "x.hevr").hits
    assert values[hits].max() < 0  # every ray's mean is negative: 0 .. p99.9 was a black picture
    png = np.asarray(Image.open(tmp_path / "x.png")).astype(int)
    obj, air = values == values[hits].max(), hits & (values == values[hits].min())
    assert png[obj].min() > png[air].max() + 100, (png[obj], png[air])
    assert (png[~hits] == 0).all()  # rays that miss the volume stay black
    assert "window:  " in out and "negative values" in out


def test_names_that_are_not_utf8_work_from_the_command_line(tmp_path, capsys, monkeypatch):
    """Issue 39, item 3: argv holds a non-UTF-8 name as surrogate escapes (os.fsdecode); every
    command writes and reads it, and prints it as its bytes (it raised UnicodeEncodeError naming
    neither option nor path)."""
    import io
    import sys

    n = str(tmp_path / os.fsdecode(b"\xff"))
    for argv in (
        ["keygen", "--bits", "256", "--out", n + ".json", "-q"],
        ["encrypt", "phantom:8", "--key", n + ".json", "--out", n + ".zarr", "--brick", "4", "-q"],
        ["render", n + ".zarr", "--out", n + ".hevr", "--size", "6x6", "-q"],
        ["slice", n + ".zarr", "--out", n + ".s.hevr", "--coronal", "3", "-q"],
        ["decrypt", n + ".hevr", "--key", n + ".json", "--out", n + ".png", "--npy", n + ".npy", "-q"],
        ["decrypt", n + ".s.hevr", "--key", n + ".json", "-q"],
        ["info", n + ".zarr"],
    ):
        raw = io.BytesIO()
        out = io.TextIOWrapper(raw, encoding="utf-8", errors="strict")  # a UTF-8 terminal's stdout
        monkeypatch.setattr(sys, "stdout", out)
        code = main(argv)
        out.flush()
        monkeypatch.undo()
        err = capsys.readouterr().err
        assert code == 0, (argv[0], err)
        assert os.fsencode(n) in raw.getvalue() and out.errors == "strict", raw.getvalue()  # its bytes; restored
    names = sorted(os.listdir(os.fsencode(str(tmp_path))))
    assert names == sorted(
        b"\xff" + s for s in (b".json", b".pub.json", b".zarr", b".hevr", b".s.hevr", b".png", b".npy", b".s.png")
    ), names


@pytest.mark.parametrize("workers", [[], ["--workers", "2"]])
def test_ctrl_c_during_encrypt_is_one_line_soon_that_says_how_to_resume(tmp_path, capsys, workers):
    """Issue 39, item 5: Ctrl-C (SIGINT to the terminal's process group) during hevr encrypt
    printed 63 lines of Dask tracebacks (--workers 2) or took 13 s to exit; now one line, within
    seconds, naming --resume; hevr info on the half-written store names the CLI flag.

    Issue 49: under load the exit took 7.3 s (bound 5 s). The line was out within 0.3 s; the rest
    was a nanny starting a new worker for the one just killed, then the interpreter's teardown of
    Dask's heap (2-5 s of a 2-core machine at load 25). Now the nannies are closed first and the
    program leaves with os._exit once its line is printed: 0.07 s (threads) and 0.2-0.3 s
    (--workers 2) measured at load 23. The bound, 3 s, leaves ten times that for a busier machine
    and still fails the old teardown (2-5 s) and the brick-long wait (13 s)."""
    import signal
    import subprocess
    import sys
    import time

    import hevr as _h

    key = tmp_path / "k.pub.json"
    _h.generate_keypair(1024)[0].save(key)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # one brick of 40³ values: ~15 s of encryption at 1024 bits, interrupted after 1 s
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hevr",
            "encrypt",
            "phantom:40",
            "--key",
            str(key),
            "--out",
            str(tmp_path / "v.zarr"),
            "--brick",
            "40",
            *workers,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env=env,
        cwd=tmp_path,
    )
    try:
        while "compute:" not in proc.stdout.readline():  # the cluster is up; the bricks are being encrypted
            assert proc.poll() is None, proc.stderr.read()
        time.sleep(1.0)
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
        _, err = proc.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    progress = [line for line in err.splitlines() if line.startswith("hevr: INFO: encrypt: ")]
    assert progress, err  # off a terminal: its progress lines, then the one error line
    assert [line for line in err.splitlines() if line not in progress] == [
        f"hevr: error: interrupted: {tmp_path / 'v.zarr'} is not finished; the bricks written "
        "are kept: run the same hevr encrypt command with --resume to encrypt the rest"
    ], err
    assert took < 3.0, took  # 0.07-0.3 s at load 23 (docstring); before: 13 s, then 2-7 s under load
    code, out, _ = run(capsys, "info", tmp_path / "v.zarr")
    assert code == 1 and "finish it with 'hevr encrypt … --resume'" in out and "resume=True" not in out


def test_local_cluster_workers_ignore_the_terminals_ctrl_c():
    import signal
    import subprocess
    import sys

    from hevr.cli.cluster import _sigint_ignored

    probe = [sys.executable, "-c", "import signal; print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN)"]
    with _sigint_ignored():
        inside = subprocess.run(probe, capture_output=True, text=True, check=True).stdout
    outside = subprocess.run(probe, capture_output=True, text=True, check=True).stdout
    assert inside.strip() == "True" and outside.strip() == "False"
    assert signal.getsignal(signal.SIGINT) is not signal.SIG_IGN  # restored here


def test_encrypt_off_a_terminal_logs_its_progress_with_rate_and_time_left(tmp_path, capsys):
    """Issue 39, item 10: nothing at all was shown when stderr was not a terminal."""
    key = tmp_path / "key.json"
    assert run(capsys, "keygen", "--bits", "256", "--out", key, "-q")[0] == 0
    code, out, err = run(capsys, "encrypt", "phantom:12", "--key", key, "--out", tmp_path / "v.zarr", "--brick", "6")
    assert code == 0, err
    lines = [line for line in err.splitlines() if line.startswith("hevr: INFO: encrypt: ")]
    assert len(lines) >= 5 and lines[-1].startswith("hevr: INFO: encrypt: 1,728/1,728 ciphertexts"), err
    assert "ciphertexts/s" in lines[-1] and any(" left" in line for line in lines), err
    code, out, err = run(capsys, "encrypt", "phantom:12", "--key", key, "--out", tmp_path / "w.zarr", "-q")
    assert code == 0 and "INFO" not in err


def test_one_brick_is_singular_and_resuming_a_complete_store_reports_no_rate(tmp_path, capsys):
    """Issue 39, item 10: "1 bricks"; --resume on a complete store printed 5,992,941 ciphertexts/s."""
    key = tmp_path / "key.json"
    assert run(capsys, "keygen", "--bits", "256", "--out", key, "-q")[0] == 0
    code, out, err = run(
        capsys, "encrypt", "phantom:8", "--key", key, "--out", tmp_path / "v.zarr", "--brick", "8", "-q"
    )
    assert code == 0 and "wrote " in out and ": 1 brick of" in out and "1 bricks" not in out, out
    code, out, err = run(
        capsys, "encrypt", "phantom:8", "--key", key, "--out", tmp_path / "v.zarr", "--brick", "8", "--resume", "-q"
    )
    assert code == 0, err
    assert "already complete (1 brick of" in out and "nothing was left to encrypt" in out
    assert "ciphertexts/s" not in out and "wrote" not in out
    code, out, _ = run(capsys, "info", tmp_path / "v.zarr")
    assert "= 1 brick\n" in out
