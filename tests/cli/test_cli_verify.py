"""``hevr info STORE --verify`` (issue 24 item 9): every brick read back, each damaged one named
by channel and index, exit 1; the temporaries an interrupted write left beside a store named in
a warning with their sizes (item 7); and FIFOs in place of what a command reads end it at once
(item 3): ``hevr decrypt FIFO``, ``hevr info FIFO``, ``hevr info``/``render`` of a store with
a FIFO inside exit non-zero within seconds (run as processes, killed if they block)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytestmark = [pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning"), pytest.mark.timeout(300)]


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def run_process(*argv, timeout: float = 120) -> subprocess.CompletedProcess:
    """``hevr ARGV`` in a child process; one that blocks past ``timeout`` is killed and fails the test."""
    try:
        return subprocess.run(
            [sys.executable, "-m", "hevr", *map(str, argv)],
            capture_output=True,
            text=True,
            timeout=timeout,
            env={**os.environ, "PYTHONWARNINGS": "ignore"},
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"hevr {' '.join(map(str, argv))} blocked for more than {timeout:g} s")


@pytest.fixture(scope="module")
def made(tmp_path_factory, keypair256):
    """A 3 x 3 x 3-brick store with a vector channel, and the key files."""
    d = tmp_path_factory.mktemp("verify")
    pub, priv = keypair256
    priv.save(d / "key.json")
    vol = np.random.default_rng(11).integers(0, 256, (9, 9, 9)).astype(np.uint8)
    hevr.encrypt_volume(vol, d / "v.zarr", pub, brick=3, vector_dims=3, progress=False)
    return d


@pytest.fixture()
def store(made, tmp_path):
    shutil.copytree(made / "v.zarr", tmp_path / "v.zarr")
    return tmp_path / "v.zarr"


def _flip(f: Path) -> None:
    b = bytearray(f.read_bytes())
    b[len(b) // 2] ^= 0x01
    f.write_bytes(bytes(b))


def test_verify_a_good_store(store, capsys):
    code, out, err = run(capsys, "info", store, "--verify", "-q")
    assert code == 0, err
    assert re.search(r"^verify: +ok: verified 27 bricks \(every ciphertext", out, re.M), out
    assert "hevr: warning" not in err


def test_verify_names_the_damaged_bricks(store, capsys):
    _flip(store / "scalar/c/2/0/1/0")
    _flip(store / "vector/c/0/1/2/2/0")
    code, out, _ = run(capsys, "info", store)  # the quick check reads no ciphertext
    assert code == 0 and "verify:" not in out
    code, out, err = run(capsys, "info", store, "--verify", "-q")
    assert code == 1, (out, err)
    assert re.search(r"^verify: +FAILED: 2 of 27 bricks damaged", out, re.M), out
    damaged = [line for line in out.splitlines() if line.startswith("damaged: ")]
    assert len(damaged) == 2
    assert damaged[0].startswith(
        "damaged: brick (1, 2, 2) of channel 'vector' cannot be read (its chunk fails its crc32c check"
    )
    assert damaged[1].startswith("damaged: brick (2, 0, 1) of channel 'scalar' ")


def test_verify_on_local_workers(store, capsys):
    _flip(store / "scalar/c/0/0/0/0")
    code, out, err = run(capsys, "info", store, "--verify", "--workers", "2", "-q")
    assert code == 1, err
    damaged = [line for line in out.splitlines() if line.startswith("damaged: ")]
    assert len(damaged) == 1 and damaged[0].startswith("damaged: brick (0, 0, 0) of channel 'scalar' cannot be read")


def test_verify_is_documented(capsys):
    try:
        main(["info", "--help"])
    except SystemExit:
        pass
    out = capsys.readouterr().out
    assert "--verify" in out and "damaged brick" in out and "hevr info vol.zarr --verify" in out
    guide = (Path(__file__).resolve().parents[2] / "docs" / "guide" / "encrypt.md").read_text()
    assert "hevr info vol.zarr --verify" in guide


def test_info_names_stale_temporaries_with_their_sizes(store, capsys):
    new = store.with_name(".v.zarr.hevr-new-1a2b3c4d")
    new.mkdir()
    (new / "x").write_bytes(b"\0" * 5000)
    store.with_name(".v.zarr.hevr-tmp-abcdef12").write_bytes(b"\0" * 300)
    store.with_name(".v.zarr.hevr-notes").write_bytes(b"mine")  # not a temporary of hevr's
    code, out, err = run(capsys, "info", store)
    assert code == 0, err
    warning = [line for line in err.splitlines() if line.startswith("hevr: warning:")]
    assert len(warning) == 1, err
    assert ".v.zarr.hevr-new-1a2b3c4d (4.9 KiB)" in warning[0] and ".v.zarr.hevr-tmp-abcdef12 (300 B)" in warning[0]
    assert "hevr-notes" not in warning[0]


# -- FIFOs: each command ends at once ----------------------------------------------------------
def test_decrypt_and_info_of_a_fifo(made, tmp_path):
    fifo = tmp_path / "frame.hevr"
    os.mkfifo(fifo)
    r = run_process("decrypt", fifo, "--key", made / "key.json", "--out", tmp_path / "f.png")
    assert r.returncode == 2 and "FRAME: expected an encrypted image" in r.stderr and "got a FIFO" in r.stderr
    r = run_process("info", fifo)
    assert (
        r.returncode == 2
        and "PATH: expected a key, store, frame or volume file (a regular file), got a FIFO" in r.stderr
    )


@pytest.mark.parametrize("rel", ["zarr.json", "scalar/zarr.json", "scalar/c/1/1/1/0"])
def test_info_of_a_store_with_a_fifo_inside(store, rel):
    (store / rel).unlink()
    os.mkfifo(store / rel)
    r = run_process("info", store)
    assert r.returncode == 1, r.stderr
    assert f"got a FIFO at {store / rel}" in r.stdout + r.stderr


def test_render_of_a_store_with_a_fifo_chunk(store, tmp_path):
    (store / "scalar/c/1/1/1/0").unlink()
    os.mkfifo(store / "scalar/c/1/1/1/0")
    r = run_process("render", store, "--out", tmp_path / "f.hevr", "--size", "8x8", "-q")
    assert r.returncode == 1 and "brick (1, 1, 1)" in r.stderr and "FIFO" in r.stderr, r.stderr
