"""``hevr encrypt --layout packed``, ``hevr info`` of a packed store, and the commands that refuse one."""

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
    code, out, _ = run(capsys, "encrypt", "phantom:12", "--key", key, "--out", store, "--layout", "packed",
                       "--pack-axis", "x", "--brick", "4", "--verifiable")
    assert code == 0 and "packed:" in out and "along x" in out and "not verified yet" in out
    ev = hevr.open_volume(store)
    assert ev.layout == "packed" and ev.packing.axis == 2 and ev.meta.tags
    priv = hevr.load_key(key)
    c = hevr.Camera.orbit(ev, azimuth=0, elevation=20, width=10, height=9, parallel=True)  # around x
    img = hevr.render(ev, c, progress=False, verify=False)
    ref = hevr.render_plain(hevr.phantom(12), c, slices="x")  # the reference of a store packed along x
    assert (np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(ev, c)).all()
    code, out, _ = run(capsys, "info", store)
    assert code == 0 and "packed:" in out and "voxels per ciphertext along x" in out
    code, _, err = run(capsys, "render", store, "--out", tmp_path / "f.hevr", "--parallel")
    assert code == 2 and "packed store" in err and "hevr.render" in err
    code, _, err = run(capsys, "pyramid", store)
    assert code != 0 and "packed store" in err
    code, _, err = run(capsys, "encrypt", "phantom:12", "--key", key, "--out", tmp_path / "v.zarr", "--pack-axis", "z")
    assert code == 2 and "--pack-axis" in err and not (tmp_path / "v.zarr").exists()
