"""Every error path of the command line: one ``hevr: error:`` line that starts with the CLI
option or argument it is about (never a Python parameter name), exit 2 for a command line that
asks for something that cannot be done as given and 1 when the data or the run failed
(:mod:`hevr.cli.exits`); and one printed axis order (x×y×z, W×H) in every command's output.

256-bit keys and 8^3 phantoms: fast, NOT secure.
"""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

import hevr
import hevr.store.writer as writer_mod
from hevr.cli import cluster as cli_cluster
from hevr.cli import exits
from hevr.cli import util as cli_util
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

# A library message names a Python parameter first ("vol: expected ...", "width, height: ...").
PYTHON_NAME = re.compile(r"[a-z_]\w*(?:\[\d+\])?(?:(?:, |/)[a-z_]\w*(?:\[\d+\])?)*: ")


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("hevr: error: "), err
    assert "Traceback" not in err
    return lines[0][len("hevr: error: ") :]


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    """One key pair (+ one of another fingerprint), two tiny stores, a frame and bad files."""
    d = tmp_path_factory.mktemp("clierr")

    def ok(*argv):
        assert main([str(a) for a in argv]) == 0, argv

    ok("keygen", "--bits", "256", "--out", d / "key.json", "-q")
    ok("keygen", "--bits", "256", "--out", d / "other.json", "-q")
    ok(
        "encrypt",
        "phantom:8",
        "--key",
        d / "key.json",
        "--out",
        d / "vol.zarr",
        "--brick",
        "4",
        "--vector-dims",
        "2",
        "-q",
    )
    ok("encrypt", "phantom:8", "--key", d / "key.json", "--out", d / "scalar.zarr", "--brick", "4", "-q")
    ok(
        "encrypt",
        "phantom:8",
        "--key",
        d / "key.json",
        "--out",
        d / "vec.zarr",
        "--brick",
        "4",
        "--no-scalar",
        "--vector-dims",
        "2",
        "-q",
    )
    ok("render", d / "vol.zarr", "--out", d / "f.hevr", "--size", "8x8", "-q")
    ok(
        "render",
        d / "vol.zarr",
        "--out",
        d / "t.hevr",
        "--size",
        "8x8",
        "--mode",
        "tf",
        "--keep-sums",
        d / "v.hevrsums",
        "-q",
    )
    ok("render", d / "vol.zarr", "--out", d / "xr.hevr", "--size", "8x8", "--keep-sums", d / "x.hevrsums", "-q")
    sums = bytearray((d / "v.hevrsums").read_bytes())
    sums[40] ^= 0x01
    (d / "tampered.hevrsums").write_bytes(bytes(sums))
    (d / "notes.txt").write_text("not a volume\n")
    (d / "garbage.npy").write_bytes(b"\x93NUMPYgarbage")
    (d / "garbage.hevr").write_bytes(b"garbage" * 10)
    (d / "bad.json").write_text("{not json")
    (d / "plain.json").write_text('{"a": 1}')
    (d / "adir").mkdir()
    np.save(d / "v2d.npy", np.zeros((8, 8), np.uint8))
    shutil.copytree(d / "vol.zarr", d / "corrupt.zarr")
    chunk = next(p for p in sorted((d / "corrupt.zarr" / "scalar" / "c").rglob("*")) if p.is_file())
    chunk.write_bytes(chunk.read_bytes()[:-7])  # truncated: the store's own chunk-size check fails
    shutil.copytree(d / "vol.zarr", d / "foreign.zarr")
    (d / "foreign.zarr" / "zarr.json").write_text(
        json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {}})
    )
    blob = bytearray((d / "f.hevr").read_bytes())
    blob[-5] ^= 0xFF
    (d / "tampered.hevr").write_bytes(bytes(blob))
    return d


E, R, INFO, DE, S = "encrypt", "render", "info", "decrypt", "upgrade-store"
P8 = "phantom:8"
# (id, argv with {d} for the fixture folder, exit code, the CLI word the message starts with)
CASES = [
    # keygen
    ("keygen-bad-bits", ["keygen", "--bits", "255", "--out", "{d}/k.json"], 2, "--bits"),
    ("keygen-exists", ["keygen", "--bits", "256", "--out", "{d}/key.json"], 2, "--out"),
    ("keygen-no-dir", ["keygen", "--bits", "256", "--out", "{d}/nodir/k.json"], 2, "--out"),
    ("keygen-out-is-folder", ["keygen", "--bits", "256", "--out", "{d}/adir"], 2, "--out"),
    (
        "keygen-bad-format",
        ["keygen", "--bits", "256", "--out", "{d}/k.json", "--format", "pem"],
        2,
        "argument --format",
    ),
    # convert-key
    ("convert-missing-key", ["convert-key", "{d}/none.json", "--out", "{d}/k2.json"], 2, "KEY"),
    ("convert-garbage-key", ["convert-key", "{d}/bad.json", "--out", "{d}/k2.json"], 2, "KEY"),
    ("convert-json-not-key", ["convert-key", "{d}/plain.json", "--out", "{d}/k2.json"], 2, "KEY"),
    ("convert-key-is-folder", ["convert-key", "{d}/adir", "--out", "{d}/k2.json"], 2, "KEY"),
    ("convert-exists", ["convert-key", "{d}/key.json", "--out", "{d}/other.json"], 2, "--out"),
    ("convert-onto-itself", ["convert-key", "{d}/key.json", "--out", "{d}/key.json", "--force"], 2, "--out"),
    ("convert-out-is-folder", ["convert-key", "{d}/key.json", "--out", "{d}/adir"], 2, "--out"),
    ("convert-no-dir", ["convert-key", "{d}/key.json", "--out", "{d}/nodir/k2.json"], 2, "--out"),
    # encrypt: the input
    ("encrypt-phantom-3", [E, "phantom:3", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    ("encrypt-phantom-text", [E, "phantom:x", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    ("encrypt-missing-input", [E, "{d}/none.npy", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    ("encrypt-unknown-input", [E, "{d}/notes.txt", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    ("encrypt-garbage-input", [E, "{d}/garbage.npy", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    ("encrypt-2d-input", [E, "{d}/v2d.npy", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    ("encrypt-empty-folder", [E, "{d}/adir", "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr"], 2, "INPUT"),
    # encrypt: the key
    ("encrypt-missing-key", [E, P8, "--key", "{d}/missing.json", "--out", "{d}/x.zarr"], 2, "--key"),
    ("encrypt-garbage-key", [E, P8, "--key", "{d}/bad.json", "--out", "{d}/x.zarr"], 2, "--key"),
    ("encrypt-json-not-key", [E, P8, "--key", "{d}/plain.json", "--out", "{d}/x.zarr"], 2, "--key"),
    ("encrypt-key-is-folder", [E, P8, "--key", "{d}/adir", "--out", "{d}/x.zarr"], 2, "--key"),
    (
        "encrypt-no-trust-scheduler",
        [E, P8, "--key", "{d}/key.json", "--out", "{d}/x.zarr", "--scheduler", "tcp://127.0.0.1:1"],
        2,
        "--key",
    ),
    (
        "encrypt-resume-other-key",
        [
            E,
            P8,
            "--key",
            "{d}/other.pub.json",
            "--out",
            "{d}/vol.zarr",
            "--resume",
            "--brick",
            "4",
            "--vector-dims",
            "2",
        ],
        2,
        "--key",
    ),
    # encrypt: the store and the options
    ("encrypt-exists", [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/vol.zarr"], 2, "--out"),
    ("encrypt-out-is-file", [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/notes.txt", "--overwrite"], 2, "--out"),
    ("encrypt-no-dir", [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/nodir/x.zarr"], 2, "--out"),
    ("encrypt-resume-missing", [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr", "--resume"], 2, "--resume"),
    (
        "encrypt-resume-overwrite",
        [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/vol.zarr", "--resume", "--overwrite"],
        2,
        "--resume",
    ),
    (
        "encrypt-resume-other-brick",
        [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/vol.zarr", "--resume", "--brick", "3", "--vector-dims", "2"],
        2,
        "--brick",
    ),
    (
        "encrypt-no-channel",
        [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr", "--no-scalar"],
        2,
        "--no-scalar",
    ),
    ("encrypt-bad-brick", [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr", "--brick", "0"], 2, "--brick"),
    (
        "encrypt-bad-spacing",
        [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr", "--spacing", "1,1"],
        2,
        "--spacing",
    ),
    (
        "encrypt-bad-range",
        [E, P8, "--key", "{d}/key.pub.json", "--out", "{d}/x.zarr", "--value-range", "1,0"],
        2,
        "--value-range",
    ),
    # render --keep-sums and recolour
    (
        "render-keep-sums-folder",
        [R, "{d}/vol.zarr", "--out", "{d}/y.hevr", "--size", "8x8", "--keep-sums", "{d}/adir"],
        2,
        "--keep-sums",
    ),
    ("recolour-missing-sums", ["recolour", "{d}/none.hevrsums", "--out", "{d}/y.hevr"], 2, "SUMS"),
    ("recolour-not-sums", ["recolour", "{d}/notes.txt", "--out", "{d}/y.hevr"], 2, "SUMS"),
    ("recolour-sums-is-folder", ["recolour", "{d}/adir", "--out", "{d}/y.hevr"], 2, "SUMS"),
    ("recolour-tampered-sums", ["recolour", "{d}/tampered.hevrsums", "--out", "{d}/y.hevr"], 1, "SUMS"),
    (
        "recolour-tf-on-xray-sums",
        ["recolour", "{d}/x.hevrsums", "--out", "{d}/y.hevr", "--tf", "0.5:red"],
        2,
        "--mode tf",
    ),
    (
        "recolour-xray-on-vector-sums",
        ["recolour", "{d}/v.hevrsums", "--out", "{d}/y.hevr", "--mode", "xray"],
        2,
        "--mode xray",
    ),
    (
        "recolour-density-with-tf",
        ["recolour", "{d}/v.hevrsums", "--out", "{d}/y.hevr", "--mode", "tf", "--density", "0.5"],
        2,
        "--density",
    ),
    (
        "recolour-duplicate-tf",
        ["recolour", "{d}/v.hevrsums", "--out", "{d}/y.hevr", "--tf", "0.5:red,0.5:blue"],
        2,
        "argument --tf",
    ),
    ("recolour-out-is-folder", ["recolour", "{d}/v.hevrsums", "--out", "{d}/adir"], 2, "--out"),
    # render: the store
    ("render-missing-store", [R, "{d}/missing.zarr", "--out", "{d}/x.hevr", "--size", "8x8"], 2, "STORE"),
    ("render-store-is-file", [R, "{d}/notes.txt", "--out", "{d}/x.hevr", "--size", "8x8"], 2, "STORE"),
    ("render-store-empty-folder", [R, "{d}/adir", "--out", "{d}/x.hevr", "--size", "8x8"], 2, "STORE"),
    ("render-foreign-zarr", [R, "{d}/foreign.zarr", "--out", "{d}/x.hevr", "--size", "8x8"], 2, "STORE"),
    ("render-corrupt-store", [R, "{d}/corrupt.zarr", "--out", "{d}/x.hevr", "--size", "8x8"], 1, "STORE"),
    (
        "render-tf-without-vector",
        [R, "{d}/scalar.zarr", "--out", "{d}/x.hevr", "--size", "8x8", "--mode", "tf"],
        2,
        "--mode",
    ),
    (
        "render-density-without-vector",
        [R, "{d}/scalar.zarr", "--out", "{d}/x.hevr", "--size", "8x8", "--density", "0.5"],
        2,
        "--mode",
    ),
    ("render-xray-without-scalar", [R, "{d}/vec.zarr", "--out", "{d}/x.hevr", "--size", "8x8"], 2, "--mode"),
    # render: options
    (
        "render-density-with-xray",
        [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--mode", "xray", "--density", "0.5"],
        2,
        "--density",
    ),
    ("render-emphasize-no-density", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--mode", "emphasize"], 2, "--mode"),
    ("render-tf-with-xray", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--mode", "xray", "--tf", "0.5:red"], 2, "--tf"),
    ("render-bad-tf", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--tf", "0.5-red"], 2, "--tf"),
    ("render-tf-colour", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--tf", "0.5:notacolour"], 2, "--tf"),
    ("render-tf-density", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--tf", "1.5:red"], 2, "--tf"),
    ("render-tf-duplicate", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--tf", "0.5:red,0.5:blue"], 2, "--tf"),
    ("render-planner-step", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--size", "8x8", "--step", "1e-9"], 2, "--step"),
    ("render-precision", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--precision", "40"], 2, "--precision"),
    ("render-bad-size", [R, "{d}/vol.zarr", "--out", "{d}/x.hevr", "--size", "0x5"], 2, "--size"),
    ("render-out-is-folder", [R, "{d}/vol.zarr", "--out", "{d}/adir", "--size", "8x8"], 2, "--out"),
    ("render-no-dir", [R, "{d}/vol.zarr", "--out", "{d}/nodir/x.hevr", "--size", "8x8"], 2, "--out"),
    # decrypt
    ("decrypt-missing-frame", [DE, "{d}/missing.hevr", "--key", "{d}/key.json"], 2, "FRAME"),
    ("decrypt-not-a-frame", [DE, "{d}/notes.txt", "--key", "{d}/key.json"], 2, "FRAME"),
    ("decrypt-garbage-frame", [DE, "{d}/garbage.hevr", "--key", "{d}/key.json"], 2, "FRAME"),
    ("decrypt-frame-is-folder", [DE, "{d}/vol.zarr", "--key", "{d}/key.json"], 2, "FRAME"),
    ("decrypt-tampered-frame", [DE, "{d}/tampered.hevr", "--key", "{d}/key.json", "--out", "{d}/t.png"], 1, "FRAME"),
    ("decrypt-missing-key", [DE, "{d}/f.hevr", "--key", "{d}/missing.json"], 2, "--key"),
    ("decrypt-public-key", [DE, "{d}/f.hevr", "--key", "{d}/key.pub.json"], 2, "--key"),
    ("decrypt-other-key", [DE, "{d}/f.hevr", "--key", "{d}/other.json", "--out", "{d}/o.png"], 2, "--key"),
    ("decrypt-garbage-key", [DE, "{d}/f.hevr", "--key", "{d}/bad.json"], 2, "--key"),
    ("decrypt-out-is-folder", [DE, "{d}/f.hevr", "--key", "{d}/key.json", "--out", "{d}/adir"], 2, "--out"),
    ("decrypt-out-not-png", [DE, "{d}/f.hevr", "--key", "{d}/key.json", "--out", "{d}/x.txt"], 2, "--out"),
    (
        "decrypt-npy-no-dir",
        [DE, "{d}/f.hevr", "--key", "{d}/key.json", "--out", "{d}/x.png", "--npy", "{d}/nodir/x.npy"],
        2,
        "--npy",
    ),
    ("decrypt-bad-window", [DE, "{d}/f.hevr", "--key", "{d}/key.json", "--window", "1,0"], 2, "--window"),
    # info
    ("info-missing", [INFO, "{d}/nothing-here"], 2, "PATH"),
    ("info-json-not-key", [INFO, "{d}/plain.json"], 2, "PATH"),
    ("info-garbage-json", [INFO, "{d}/bad.json"], 2, "PATH"),
    ("info-garbage-npy", [INFO, "{d}/garbage.npy"], 2, "PATH"),
    ("info-unknown-file", [INFO, "{d}/notes.txt"], 2, "PATH"),
    ("info-garbage-frame", [INFO, "{d}/garbage.hevr"], 2, "PATH"),
    ("info-foreign-zarr", [INFO, "{d}/foreign.zarr"], 2, "PATH"),
    ("info-tampered-frame", [INFO, "{d}/tampered.hevr"], 1, "PATH"),
    # upgrade-store
    ("upgrade-missing-old", [S, "{d}/missing.zarr", "{d}/new.zarr"], 2, "OLD"),
    ("upgrade-old-is-file", [S, "{d}/notes.txt", "{d}/new.zarr"], 2, "OLD"),
    ("upgrade-old-is-format-2", [S, "{d}/vol.zarr", "{d}/new.zarr"], 2, "OLD"),
    ("upgrade-new-exists", [S, "{d}/vol.zarr", "{d}/scalar.zarr"], 2, "NEW"),
    ("upgrade-new-no-dir", [S, "{d}/vol.zarr", "{d}/nodir/new.zarr"], 2, "NEW"),
    # demo, bench
    ("demo-size", ["demo", "--size", "3"], 2, "--size"),
    ("demo-image", ["demo", "--image", "0x5"], 2, "--image"),
    ("demo-brick", ["demo", "--brick", "0"], 2, "--brick"),
    ("demo-missing-input", ["demo", "--input", "{d}/none.npy", "--out", "{d}/demo"], 2, "--input"),
    ("demo-unknown-input", ["demo", "--input", "{d}/notes.txt", "--out", "{d}/demo"], 2, "--input"),
    ("demo-out-is-file", ["demo", "--out", "{d}/notes.txt", "--size", "4", "--bits", "256"], 2, "--out"),
    ("bench-quick-paper", ["bench", "--quick", "--paper"], 2, "--paper"),
    ("bench-only", ["bench", "--only", "nope", "--out", "{d}/bench"], 2, "--only"),
    ("bench-report-only", ["bench", "--report-only", "--out", "{d}/adir"], 2, "--out"),
]


@pytest.mark.parametrize("argv, code, word", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_error_path(d, capsys, argv, code, word):
    got, out, err = run(capsys, *(a.replace("{d}", str(d)) for a in argv))
    msg = one_error_line(err)
    assert got == code, (got, msg)
    assert msg.startswith((f"{word}:", f"{word} ", f"{word},", f"argument {word}:")), msg
    assert not PYTHON_NAME.match(msg), f"a Python name leads: {msg}"
    for python in ("vector_dims=", "overwrite=True", "resume=True", "encrypt_volume(", "private_key"):
        assert python not in msg, msg


def test_every_case_id_is_unique():
    ids = [c[0] for c in CASES]
    assert len(ids) == len(set(ids))


def test_the_failed_commands_left_the_fixtures_alone(d):
    """The refused runs above wrote nothing: the stores, the frame and the keys still work."""
    assert hevr.open_volume(d / "vol.zarr").shape == (8, 8, 8)
    assert not (d / "x.zarr").exists() and not (d / "x.hevr").exists() and not (d / "new.zarr").exists()
    assert (
        not (d / "y.hevr").exists()
        and not (d / "k2.json").exists()
        and hevr.load_sums(d / "v.hevrsums").channel == "vector"
    )
    assert hevr.load_key(d / "key.json").fingerprint == hevr.load_key(d / "key.pub.json").fingerprint


def test_decrypt_public_key_message(d, capsys):
    code, _, err = run(capsys, "decrypt", d / "f.hevr", "--key", d / "key.pub.json")
    assert code == 2
    assert one_error_line(err) == f"--key: expected a private key file, got a public key ({d / 'key.pub.json'})"


@pytest.mark.parametrize(
    "argv, code, needle",
    [
        ([], 2, "a command is required"),
        (["frobnicate"], 2, "invalid choice"),
    ],
)
def test_no_or_unknown_command(capsys, argv, code, needle):
    got, _, err = run(capsys, *argv)
    assert got == code and needle in one_error_line(err)


def test_unreachable_scheduler_is_a_run_failure(d, capsys, monkeypatch):
    def refuse(*args, **kw):
        raise OSError("connection refused")

    monkeypatch.setattr(cli_cluster, "Client", refuse)
    code, _, err = run(
        capsys,
        "encrypt",
        "phantom:8",
        "--key",
        d / "key.pub.json",
        "--out",
        d / "s.zarr",
        "--scheduler",
        "tcp://127.0.0.1:1",
    )
    msg = one_error_line(err)
    assert code == 1 and msg.startswith("--scheduler: cannot connect") and "connection refused" in msg


def test_crashed_worker_then_incomplete_store(d, capsys, monkeypatch, tmp_path):
    """A worker that dies is a run failure (1); the store it leaves is incomplete data (1), and
    the message says how to finish it in the CLI's words."""
    real, calls = writer_mod._encrypt_brick, []

    def flaky(*args, **kw):
        if len(calls) >= 3:
            raise RuntimeError("worker died")
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(writer_mod, "_encrypt_brick", flaky)
    store = tmp_path / "half.zarr"
    code, _, err = run(
        capsys, "encrypt", "phantom:8", "--key", d / "key.json", "--out", store, "--brick", "4", "--workers", "0", "-q"
    )
    msg = one_error_line(err)
    assert code == 1 and "worker died" in msg and "--verbose" in msg
    monkeypatch.setattr(writer_mod, "_encrypt_brick", real)
    code, _, err = run(capsys, "render", store, "--out", tmp_path / "x.hevr", "--size", "8x8")
    msg = one_error_line(err)
    assert code == 1 and msg.startswith("STORE: ") and "incomplete" in msg and "--resume" in msg
    code, _, err = run(
        capsys, "encrypt", "phantom:8", "--key", d / "key.json", "--out", store, "--brick", "4", "--resume", "-q"
    )
    assert code == 0, err


@pytest.mark.parametrize(
    "exc, code",
    [
        (hevr.ParameterError("x"), 2),
        (hevr.MissingFileError("key", "a key file", "k.json"), 2),
        (hevr.ExistingFileError("path", "k.json"), 2),
        (hevr.StoreExistsError("x"), 2),
        (hevr.KeyMismatchError("x"), 2),
        (hevr.RenderPlanError("x"), 2),
        (hevr.InvalidKeyError("x"), 2),
        (hevr.VolumeFormatError("x"), 2),
        (cli_util.UsageError("x"), 2),
        (hevr.CorruptStoreError("x"), 1),
        (hevr.IntegrityError("x"), 1),
        (hevr.IncompleteStoreError("x"), 1),
        (hevr.PlaintextOverflowError("x"), 1),
        (hevr.MissingDependencyError("x"), 1),
        (hevr.MemoryLimitError("x"), 1),
        (OSError(28, "No space left on device", "x"), 1),
        (RuntimeError("x"), 1),
        (KeyboardInterrupt(), 130),
    ],
)
def test_exit_status_by_error_class(exc, code):
    assert exits.exit_code(exc) == code


@pytest.mark.parametrize(
    "command, text, want",
    [
        ("encrypt", "vol: expected a 3-D array", "INPUT: expected a 3-D array"),
        ("encrypt", "private_key: expected a key", "--key: expected a key"),
        (
            "encrypt",
            "scalar/vector_dims: expected at least one channel",
            "--no-scalar, --vector-dims: expected at least",
        ),
        ("render", "width, height: expected at most", "--size: expected at most"),
        ("render", "nodes[1]: expected a colour", "--tf: expected a colour"),
        ("render", "ev: expected an EncryptedVolume", "STORE: expected an EncryptedVolume"),
        ("decrypt", "private_key: the image was encrypted under key", "--key: the image was encrypted under key"),
        ("upgrade-store", "dst: x already exists", "NEW: x already exists"),
        (
            "keygen",
            "path: expected no file at k.json (pass overwrite=True to replace it), found one",
            "--out: expected no file at k.json (pass --force to replace it), found one",
        ),
    ],
)
def test_python_names_become_cli_words(command, text, want):
    class Args:
        pass

    args = Args()
    args.command = command
    assert exits.cli_message(hevr.ParameterError(text), args).startswith(want)


def test_help_documents_the_exit_status(capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0 and "exit status" in out and "cannot be done as given" in out and "130" in out
    assert "x×y×z" in out and "W×H" in out


# -- one printed axis order ---------------------------------------------------------------------


def test_every_command_prints_the_same_axis_order(tmp_path, d, capsys):
    """A (z, y, x) = (4, 5, 6) volume, spacing 1,2,3 and bricks BZ,BY,BX = 2,3,4: every output
    says x×y×z = 6×5×4 and x, y, z = 1, 2, 3; images say W×H."""
    np.save(tmp_path / "v.npy", np.arange(120, dtype=np.uint8).reshape(4, 5, 6))
    size, spacing, brick = "x×y×z = 6×5×4", "x, y, z = 1, 2, 3", "x×y×z = 4×3×2"
    code, enc, err = run(
        capsys,
        "encrypt",
        tmp_path / "v.npy",
        "--key",
        d / "key.json",
        "--out",
        tmp_path / "v.zarr",
        "--spacing",
        "1,2,3",
        "--brick",
        "2,3,4",
        "-q",
    )
    assert code == 0, err
    assert size in enc and spacing in enc and f"bricks of {brick}" in enc
    code, info_store, err = run(capsys, "info", tmp_path / "v.zarr")
    assert code == 0, err
    assert size in info_store and spacing in info_store and brick in info_store
    code, info_vol, err = run(capsys, "info", tmp_path / "v.npy")
    assert code == 0, err
    assert size in info_vol
    code, ren, err = run(capsys, "render", tmp_path / "v.zarr", "--out", tmp_path / "v.hevr", "--size", "8x6", "-q")
    assert code == 0, err
    assert size in ren and "W×H = 8×6" in ren
    code, info_img, err = run(capsys, "info", tmp_path / "v.hevr")
    assert code == 0, err
    assert "W×H = 8×6" in info_img
    code, dec, err = run(capsys, "decrypt", tmp_path / "v.hevr", "--key", d / "key.json", "-q")
    assert code == 0, err
    assert "W×H = 8×6" in dec
    for text in (enc, info_store, info_vol, ren, info_img, dec):  # no other order, no unlabelled tuple
        assert "(4, 5, 6)" not in text and "(6, 5, 4)" not in text and "nz" not in text and "height, width" not in text


# -- words of the command line (issue 29, item 7) ---------------------------------------------------------
def test_a_value_that_starts_with_a_minus_is_checked_as_that_value(d, capsys, tmp_path):
    """``--size -5x-5`` is the size option's own error, not argparse's "expected one argument"; a
    negative angle or value range still reads."""
    code, _, err = run(capsys, "render", d / "vol.zarr", "--out", tmp_path / "x.hevr", "--size", "-5x-5")
    assert code == 2 and one_error_line(err).startswith(
        "argument --size: expected WIDTHxHEIGHT in pixels such as 150x150, got '-5x-5'"
    ), err
    code, _, err = run(
        capsys,
        "render",
        d / "vol.zarr",
        "--out",
        tmp_path / "y.hevr",
        "--size",
        "6x5",
        "--azimuth",
        "-30",
        "--elevation",
        "-10",
        "-q",
    )
    assert code == 0, err


def test_a_reader_that_leaves_ends_the_command_quietly(d):
    """``hevr info … | head -1``: when stdout's reader has gone the command stops with SIGPIPE's
    status (141) and writes nothing on stderr — no "Broken pipe", no "Exception ignored"."""
    import os
    import subprocess
    import sys

    r, w = os.pipe()
    os.close(r)  # the reader is gone before hevr writes a byte
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "hevr", "info", str(d / "vol.zarr")], stdout=w, stderr=subprocess.PIPE, timeout=120
        )
    finally:
        os.close(w)
    assert proc.returncode == 141 and proc.stderr == b"", (proc.returncode, proc.stderr)


@pytest.mark.parametrize("address", ["garbage://x", "tcp://"])
def test_a_scheduler_address_dask_cannot_parse_names_the_option(d, capsys, address):
    code, _, err = run(
        capsys, "encrypt", "phantom:8", "--key", d / "key.pub.json", "--out", d / "s.zarr", "--scheduler", address
    )
    msg = one_error_line(err)
    assert code == 2, msg
    want = f"--scheduler: expected a Dask scheduler address like tcp://10.0.0.5:8786, got {address!r}"
    assert msg.startswith(want), msg
    assert not (d / "s.zarr").exists()


@pytest.mark.timeout(120)
@pytest.mark.parametrize("command", ["encrypt", "demo"])
def test_a_fifo_as_the_input_volume_is_named_as_the_input(d, capsys, tmp_path, command):
    """A FIFO given as the volume was reported as --out (the loader's 'path')."""
    import os

    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)  # reading it would block forever
    argv = (
        ["encrypt", fifo, "--key", d / "key.pub.json", "--out", tmp_path / "o.zarr"]
        if command == "encrypt"
        else ["demo", "--input", fifo, "--out", tmp_path / "demo"]
    )
    code, _, err = run(capsys, *argv)
    msg = one_error_line(err)
    word = "INPUT" if command == "encrypt" else "--input"
    assert code == 2 and msg == f"{word}: expected a volume file (a regular file), got a FIFO at {fifo}", msg


@pytest.fixture
def read_only(tmp_path, monkeypatch):
    """A folder on a read-only filesystem: mode 0555, and statvfs reports it mounted read-only
    (root writes through 0555, and a test cannot mount; the check before any work reads both)."""
    import os
    import types
    from pathlib import Path

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    real = os.statvfs

    def statvfs(path):
        st = real(path)
        if Path(path).absolute() == ro:
            return types.SimpleNamespace(f_flag=st.f_flag | os.ST_RDONLY)
        return st

    monkeypatch.setattr(os, "statvfs", statvfs)
    yield ro
    ro.chmod(0o755)


def _outputs_into(d, tmp_path, ro):
    """(argv, the option named) of every command that writes a file the command line names."""
    return [
        (["keygen", "--bits", "256", "--out", ro / "k.json"], "--out"),
        (["encrypt", "phantom:8", "--key", d / "key.pub.json", "--out", ro / "x.zarr", "--brick", "4"], "--out"),
        (["render", d / "vol.zarr", "--out", ro / "f.hevr", "--size", "8x8"], "--out"),
        (
            ["render", d / "vol.zarr", "--out", tmp_path / "f.hevr", "--size", "8x8", "--keep-sums", ro / "x.hevrsums"],
            "--keep-sums",
        ),
        (["decrypt", d / "f.hevr", "--key", d / "key.json", "--out", ro / "f.png"], "--out"),
        (["convert-key", d / "key.json", "--out", ro / "k2.json"], "--out"),
        (["demo", "--out", ro, "--size", "4", "--bits", "256", "--image", "8x8"], "--out"),
        (["demo", "--out", ro / "demo", "--size", "4", "--bits", "256", "--image", "8x8"], "--out"),
        (["demo", "--out", ro / "a" / "demo", "--size", "4", "--bits", "256", "--image", "8x8"], "--out"),
    ]


@pytest.mark.parametrize("case", range(9))
def test_a_read_only_output_folder_fails_the_run_naming_the_option_and_the_cause(d, capsys, tmp_path, read_only, case):
    """encrypt, render, decrypt, keygen and --keep-sums said 'permission denied' and exited 2, demo
    'Read-only file system' and 1: one rule now (an environment failure, exit 1) and the true cause."""
    argv, option = _outputs_into(d, tmp_path, read_only)[case]
    code, _, err = run(capsys, *argv)
    msg = one_error_line(err)
    assert code == 1, msg
    assert msg == f"{option}: writing into {read_only}: Read-only file system (EROFS)", msg
    assert list(read_only.iterdir()) == [] and not (tmp_path / "f.hevr").exists()


def test_an_output_folder_without_write_permission_fails_the_run(d, capsys, tmp_path, monkeypatch):
    """No write permission (0555): exit 1 and 'Permission denied (EACCES)' — also as root, whom
    mode bits do not stop (os.access answers as for any other user there)."""
    import os

    ro = tmp_path / "locked"
    ro.mkdir()
    ro.chmod(0o555)
    if os.geteuid() == 0:
        real = os.access
        monkeypatch.setattr(
            os, "access", lambda p, mode, **kw: False if str(p) == str(ro) and mode & os.W_OK else real(p, mode, **kw)
        )
    try:
        code, _, err = run(capsys, "render", d / "vol.zarr", "--out", ro / "f.hevr", "--size", "8x8")
        msg = one_error_line(err)
        assert code == 1 and msg == f"--out: writing into {ro}: Permission denied (EACCES)", msg
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_local_workers_get_time_to_start_on_a_busy_machine(monkeypatch):
    """--workers N: the local cluster starts with Dask's connect timeout raised to 120 s (a worker
    process that starts slowly on a loaded machine is not a network failure; issue 49), carried to
    the workers by the nannies' config; a larger configured timeout is kept."""
    import dask

    seen = []

    class Recording:
        def __init__(self, **kw):
            seen.append(dask.config.get("distributed.comm.timeouts.connect"))

        def close(self):
            pass

    class NoClient:
        def __init__(self, cluster):
            pass

        def close(self):
            pass

    monkeypatch.setattr(cli_cluster, "LocalCluster", Recording)
    monkeypatch.setattr(cli_cluster, "Client", NoClient)
    for configured, expected in (("30s", 120.0), ("10m", 600.0)):
        with dask.config.set({"distributed.comm.timeouts.connect": configured}):
            with cli_cluster.dask_client(workers=2):
                pass
            assert dask.config.get("distributed.comm.timeouts.connect") == configured  # only while starting
        assert seen[-1] == expected
