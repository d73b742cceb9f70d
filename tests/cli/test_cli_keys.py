"""``hevr keygen --format phe`` and ``hevr convert-key``: key files that python-paillier's own
``pheutil`` reads and writes, used end to end by the other commands.

256-bit keys: fast, NOT secure.
"""

from __future__ import annotations

import json
import stat

import pytest
from click.testing import CliRunner
from phe import command_line as pheutil

import hevr
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _ok(capsys, *argv) -> str:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def _phe(*argv) -> str:
    res = CliRunner().invoke(pheutil.cli, [str(a) for a in argv], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return res.output


def test_keygen_phe_pair_is_pheutils(tmp_path, capsys):
    out = _ok(capsys, "keygen", "--bits", "256", "--out", tmp_path / "k.json", "--format", "phe")
    assert "pheutil" in out
    assert stat.S_IMODE((tmp_path / "k.json").stat().st_mode) == 0o600
    assert json.loads((tmp_path / "k.json").read_text())["kty"] == "DAJ"
    # pheutil encrypts with our public file and decrypts with our private file
    _phe("encrypt", tmp_path / "k.pub.json", "12345", "--output", tmp_path / "c.json")
    _phe("decrypt", tmp_path / "k.json", tmp_path / "c.json", "--output", tmp_path / "m.txt")
    assert float((tmp_path / "m.txt").read_text()) == 12345  # pheutil prints its number as a float


def test_a_pheutil_key_drives_every_command(tmp_path, capsys):
    _phe("genpkey", "--keysize", "256", tmp_path / "phe.json")
    _phe("extract", tmp_path / "phe.json", tmp_path / "phe.pub.json")
    _ok(
        capsys,
        "encrypt",
        "phantom:8",
        "--key",
        tmp_path / "phe.pub.json",
        "--out",
        tmp_path / "v.zarr",
        "--brick",
        "4",
        "-q",
    )
    _ok(capsys, "render", tmp_path / "v.zarr", "--out", tmp_path / "f.hevr", "--size", "8x8", "-q")
    _ok(capsys, "decrypt", tmp_path / "f.hevr", "--key", tmp_path / "phe.json", "--npy", tmp_path / "f.npy", "-q")
    out = _ok(capsys, "info", tmp_path / "phe.json")
    assert hevr.load_key(tmp_path / "phe.json").public_key.fingerprint in out and "pheutil" in out


def test_convert_key_round_trip(tmp_path, capsys):
    _ok(capsys, "keygen", "--bits", "256", "--out", tmp_path / "k.json", "-q")
    out = _ok(capsys, "convert-key", tmp_path / "k.json", "--out", tmp_path / "p.json")
    assert "cannot hold the key's policy" in str(out)  # pheutil's file has no place for require_tags
    _ok(capsys, "convert-key", tmp_path / "p.json", "--out", tmp_path / "back.json", "--format", "hevr")
    _ok(capsys, "convert-key", tmp_path / "k.pub.json", "--out", tmp_path / "p.pub.json")
    a, b = hevr.load_key(tmp_path / "k.json"), hevr.load_key(tmp_path / "back.json")
    assert (a.p, a.q) == (b.p, b.q)
    back, orig = json.loads((tmp_path / "back.json").read_text()), json.loads((tmp_path / "k.json").read_text())
    assert orig.pop("policy") == {"require_tags": True} and back.pop("policy") == {"require_tags": False}
    assert back == orig
    assert stat.S_IMODE((tmp_path / "p.json").stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "p.pub.json").stat().st_mode) == 0o644
    assert isinstance(hevr.load_key(tmp_path / "p.pub.json"), hevr.PublicKey)
    # pheutil reads the converted public key
    _phe("encrypt", tmp_path / "p.pub.json", "7", "--output", tmp_path / "c.json")
    _phe("decrypt", tmp_path / "p.json", tmp_path / "c.json", "--output", tmp_path / "m.txt")
    assert float((tmp_path / "m.txt").read_text()) == 7
