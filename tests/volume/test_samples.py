"""hevr.sample_scan: a real scan every installation with the io extra reads offline (issue 29, item 6)."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main

pytest.importorskip("nibabel")


def test_the_sample_mri_is_a_real_scan_in_ras():
    path = hevr.sample_scan()
    assert path.is_file() and path.name == "anatomical.nii"
    scan = hevr.read_scan(path)
    assert scan.volume.shape == (25, 41, 33) and scan.volume.dtype == np.int16
    assert scan.frame == "RAS" and scan.spacing == pytest.approx((2.0, 2.0, 2.0))
    assert 1000 < float(np.ptp(scan.volume)) and len(np.unique(scan.volume)) > 1000  # real data, not a mask
    with pytest.raises(hevr.ParameterError, match="^name: expected one of"):
        hevr.sample_scan("ct")


def test_the_sample_mri_renders_within_the_bound(tmp_path, keypair256):
    """Encrypted and rendered from the front (RAS+ anterior view): every mode within error_bound
    of render_plain, which takes the scan (and its spacing) as encrypt_volume does."""
    scan = hevr.read_scan(hevr.sample_scan())
    value_range = (-700.0, 30500.0)
    ev = hevr.encrypt_volume(
        scan, tmp_path / "mri.zarr", keypair256[1], brick=16, vector_dims=3, value_range=value_range, progress=False
    )
    assert ev.frame == "RAS" and ev.spacing == pytest.approx((2.0, 2.0, 2.0))
    cam = hevr.Camera.orbit(ev, view="anterior", azimuth=20, width=12, height=10)
    for mode, kw in (("xray", {}), ("tf", {"nodes": [(0.3, "blue"), (0.6, "orange")]})):
        got = hevr.render(ev, cam, mode=mode, progress=False, **kw).decrypt(keypair256[1])
        ref = hevr.render_plain(scan, cam, mode=mode, value_range=value_range, vector_dims=3, **kw)
        assert np.count_nonzero(ref) > 20 and (np.abs(got - ref) <= hevr.error_bound(ev, cam, mode, **kw)).all()


def test_the_command_line_reads_sample_mri(tmp_path, capsys):
    assert main(["info", "sample:mri"]) == 0
    out = capsys.readouterr().out
    assert "anatomical.nii" in out and "33×41×25 voxels" in out and "RAS+ patient frame" in out
    assert main(["keygen", "--bits", "256", "--out", str(tmp_path / "key.json"), "-q"]) == 0
    assert (
        main(
            [
                "encrypt",
                "sample:mri",
                "--key",
                str(tmp_path / "key.json"),
                "--out",
                str(tmp_path / "m.zarr"),
                "--value-range=-700,30500",
                "-q",
            ]
        )
        == 0
    )
    assert hevr.open_volume(tmp_path / "m.zarr").shape == (25, 41, 33)
    capsys.readouterr()
    assert main(["encrypt", "sample:ct", "--key", str(tmp_path / "key.json"), "--out", str(tmp_path / "c.zarr")]) == 2
    assert "sample:NAME with NAME one of mri" in capsys.readouterr().err
