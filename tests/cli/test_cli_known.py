"""``hevr known list/export/import`` (issue 47) and ``hevr render --trust-store --untagged``: the
key holder's known stores on the command line, with the exit rule of every command (0 done, 2 the
command line, 1 the data: a forged entry)."""

from __future__ import annotations

import json

import dask
import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.store.known import known_stores

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")
VOL = np.random.default_rng(3).integers(0, 256, (8, 8, 8)).astype(np.uint8)


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def setup(keypair256, tmp_path, monkeypatch):
    pub, priv = keypair256
    key = tmp_path / "key.json"
    priv.save(key)
    pub.save(tmp_path / "key.pub.json")
    a = tmp_path / "a" / "known_stores.json"
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(a))
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(VOL, tmp_path / "v.zarr", priv, brick=4, progress=False, verifiable=True)
    return tmp_path, key, a, ev


def test_list_export_import(setup, capsys, monkeypatch):
    d, key, a, ev = setup
    code, out, _ = run(capsys, "known", "list")
    assert code == 0 and "1 entry" in out and str(ev.path) in out and "not checked: no --key" in out
    code, out, _ = run(capsys, "known", "list", "--key", key)
    assert code == 0 and "MAC ok" in out and ev.meta.store_id in out
    code, out, _ = run(capsys, "known", "export", d / "x.json", "--key", key)
    assert code == 0 and "exported 1 entry" in out
    code, _, err = run(capsys, "known", "export", d / "x.json", "--key", key)
    assert code == 2 and "x.json" in err  # exists: --force replaces it
    assert run(capsys, "known", "export", d / "x.json", "--key", key, "--force")[0] == 0
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(d / "b" / "known_stores.json"))  # machine B
    code, out, _ = run(capsys, "known", "import", d / "x.json", "--key", key)
    assert code == 0 and "1 name added or changed" in out
    assert known_stores()[str(ev.path)].store_id == ev.meta.store_id
    assert run(capsys, "known", "import", d / "missing.json", "--key", key)[0] == 2
    code, _, err = run(capsys, "known", "import", d / "x.json", "--key", d / "key.pub.json")
    assert code == 2 and "private key" in err
    assert run(capsys, "known", "export", d / "y.json")[0] == 2  # --key is required


def test_a_forged_entry_exits_1(setup, capsys):
    d, key, a, ev = setup
    doc = json.loads(a.read_text())
    doc["stores"][str(ev.path)]["verifiable"] = False  # downgrade, the MAC kept
    a.write_text(json.dumps(doc))
    code, _, err = run(capsys, "known", "list", "--key", key)
    assert code == 1 and "does not carry the key holder's MAC" in err and str(a) in err
    assert run(capsys, "known", "export", d / "x.json", "--key", key)[0] == 1
    assert run(capsys, "known", "list")[0] == 0  # without the key: listed, used only to refuse


def test_a_damaged_file_is_named(setup, capsys):
    _, _, a, _ = setup
    a.write_text("[" * 100_000)
    code, _, err = run(capsys, "known", "list")
    assert code == 2 and str(a) in err and "nested too deeply" in err


def test_trust_store_untagged_on_the_command_line(keypair256, tmp_path, monkeypatch, capsys):
    pub, priv = keypair256
    if not hasattr(priv, "with_policy"):
        pytest.skip("PrivateKey.require_tags has not landed")
    key = tmp_path / "strict.json"
    priv.with_policy(require_tags=True).save(key)
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(tmp_path / "k" / "known_stores.json"))
    with dask.config.set(scheduler="sync"):
        plain = hevr.encrypt_volume(VOL, tmp_path / "p.zarr", pub, brick=4, progress=False)
    argv = ["render", plain.path, "--key", key, "--size", "8x8", "-q", "--trust-store"]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "a.hevr")
    assert code == 1 and "requires tags" in err and "--untagged" in err
    code, out, _ = run(capsys, *argv, "--untagged", "--out", tmp_path / "b.hevr")
    assert code == 0 and "accepted without tags" in out
    assert known_stores()[str(plain.path)].accepted_untagged
    code, _, err = run(
        capsys, "render", plain.path, "--key", key, "--size", "8x8", "--untagged", "--out", tmp_path / "c.hevr"
    )
    assert code == 2 and "--untagged: expected --trust-store" in err
