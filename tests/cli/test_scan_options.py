"""The command line for real scans: ``render --view``, ``encrypt --modality`` and the range hint,
``--tf`` presets, the DICOM options of ``encrypt`` and ``hevr info`` of a DICOM folder.

256-bit keys and tiny volumes: fast, NOT secure.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr import Camera
from hevr.cli.main import main

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

CT = (-1024.0, 3071.0)


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _ok(capsys, *argv) -> tuple[str, str]:
    code, out, err = _run(capsys, *argv)
    assert code == 0, err
    return out, err


def _fails(capsys, *argv) -> str:
    code, out, err = _run(capsys, *argv)
    assert code == 2, (code, out, err)
    assert err.count("\n") == 1, err  # one line
    return err


def _hu() -> np.ndarray:
    """A tiny int16 CT in Hounsfield units, (z, y, x): air, soft tissue, a bone block at right-anterior-superior."""
    vol = np.full((5, 6, 7), -1000, np.int16)
    vol[1:4, 1:5, 1:6] = 40
    vol[3:5, 4:6, 5:7] = 1200
    return vol


def _write_nifti(path: Path, hu: np.ndarray) -> Path:
    nib = pytest.importorskip("nibabel")
    nib.save(nib.Nifti1Image(hu.transpose(2, 1, 0), np.diag([1.0, 1.0, 1.5, 1.0])), str(path))
    return path


def _write_dicom(
    folder: Path, hu: np.ndarray, series: str = "1.2.826.0.1.3680043.2.1", number: int = 1, modality: str = "CT"
) -> Path:
    """Axial CT slices (LPS: rows run posterior, columns left), stored + 1024 with intercept -1024."""
    pytest.importorskip("pydicom")
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder.mkdir(parents=True, exist_ok=True)
    for k, plane in enumerate(hu):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = CTImageStorage, generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID, ds.SOPInstanceUID = meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID
        ds.SeriesInstanceUID, ds.SeriesNumber, ds.Modality = series, number, modality
        ds.SeriesDescription = f"series {number}"
        ds.Rows, ds.Columns = plane.shape
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
        ds.PixelSpacing, ds.SliceThickness = [1.0, 1.0], 1.5
        ds.ImageOrientationPatient = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        ds.ImagePositionPatient = [0.0, 0.0, 1.5 * k]
        ds.InstanceNumber, ds.RescaleIntercept, ds.RescaleSlope = k + 1, -1024, 1
        ds.PixelData = (plane.astype(np.int32) + 1024).astype("<i2").tobytes()
        ds.save_as(folder / f"{series[-3:]}-IM{k:03d}.dcm", enforce_file_format=True)
    return folder


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    d = tmp_path_factory.mktemp("scan-keys")
    assert main(["keygen", "--bits", "256", "--out", str(d / "key.json"), "-q"]) == 0
    return d / "key.json"


@pytest.fixture(scope="module")
def ct_store(tmp_path_factory, keys):
    """A CT NIfTI encrypted with --modality CT (vector channel for --tf)."""
    d = tmp_path_factory.mktemp("ct")
    src = _write_nifti(d / "ct.nii.gz", _hu())
    assert (
        main(
            [
                "encrypt",
                str(src),
                "--key",
                str(keys),
                "--out",
                str(d / "ct.zarr"),
                "--modality",
                "CT",
                "--vector-dims",
                "6",
                "--brick",
                "4",
                "-q",
            ]
        )
        == 0
    )
    return d / "ct.zarr"


def _decrypt(keys, frame, **colouring):
    return hevr.load_image(frame).decrypt(hevr.load_key(keys), **colouring)


# -- encrypt: the value range ---------------------------------------------------------------------
def test_ct_nifti_with_modality_records_the_hounsfield_range(ct_store):
    ev = hevr.open_volume(ct_store)
    assert ev.value_range == CT
    assert ev.meta.dtype == "int16"


def test_ct_dicom_gets_the_ct_range_from_its_header(tmp_path, keys, capsys):
    src = _write_dicom(tmp_path / "dicom", _hu())
    out, err = _ok(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "d.zarr", "-q")
    assert hevr.open_volume(tmp_path / "d.zarr").value_range == CT
    assert "the CT range (the file's modality is CT)" in out and "RAS+ patient frame" in out
    assert "warning" not in err  # the data fill a good part of the CT range: no hint
    # --value-range still wins
    _ok(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "e.zarr", "--value-range=-1000,2000", "-q")
    assert hevr.open_volume(tmp_path / "e.zarr").value_range == (-1000.0, 2000.0)


def test_no_modality_keeps_the_dtype_range_and_hints(tmp_path, keys, capsys):
    src = _write_nifti(tmp_path / "mr.nii.gz", (_hu() + 1000) // 4)  # 0 .. 550: a tiny band of int16
    out, err = _ok(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "m.zarr", "-q")
    assert hevr.open_volume(tmp_path / "m.zarr").value_range == (-32768.0, 32767.0)
    hint = [line for line in err.splitlines() if "nearly flat" in line]
    assert len(hint) == 1 and hint[0].startswith("hevr: warning: the data span 0 .. 550")
    assert "--modality" in hint[0] and "--value-range" in hint[0]
    # hevr info says the same before anything is encrypted
    out, _ = _ok(capsys, "info", src)
    assert "frame:" in out and "RAS+" in out and "modality: -" in out and "nearly flat" in out
    # MR: the 12-bit range, and the hint is gone
    out, err = _ok(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "m2.zarr", "--modality", "mr", "-q")
    assert hevr.open_volume(tmp_path / "m2.zarr").value_range == (0.0, 4095.0)
    assert "nearly flat" not in err


def test_the_hint_never_reaches_the_store(tmp_path, keys, capsys):
    src = _write_nifti(tmp_path / "v.nii.gz", (_hu() + 1000) // 4)
    _ok(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "v.zarr", "-q")
    doc = json.loads((tmp_path / "v.zarr" / "zarr.json").read_text())

    def leaves(x):  # every number and string of the document (n and the digests are long strings)
        if isinstance(x, dict):
            return [v for item in x.values() for v in leaves(item)]
        if isinstance(x, list):
            return [v for item in x for v in leaves(item)]
        return [x]

    values = leaves(doc)
    assert 550 not in [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
    assert not any(isinstance(v, str) and ("span" in v or "flat" in v) for v in values)


# -- render --view ---------------------------------------------------------------------------------
def test_render_view_is_the_python_camera(ct_store, keys, tmp_path, capsys):
    argv = ["--size", "9x8", "--parallel", "--azimuth", "20", "--elevation", "10"]
    out, _ = _ok(
        capsys,
        "render",
        ct_store,
        "--out",
        tmp_path / "a.hevr",
        "--view",
        "anterior",
        *argv,
        "--keep-sums",
        tmp_path / "a.hevrsums",
        "-q",
    )
    assert "anterior view, azimuth 20, elevation 10" in out
    ev = hevr.open_volume(ct_store)
    cam = Camera.orbit(ev, azimuth=20, elevation=10, width=9, height=8, parallel=True, view="anterior")
    assert hevr.load_sums(tmp_path / "a.hevrsums").camera == cam
    got = _decrypt(keys, tmp_path / "a.hevr")
    python = hevr.render(ev, cam).decrypt(hevr.load_key(keys))
    assert np.array_equal(got, python)
    ref = hevr.render_plain(_hu(), cam, spacing=ev.spacing, value_range=ev.value_range)
    assert np.all(np.abs(got - ref) <= hevr.error_bound(ev, cam))
    # the view matters: the plain orbit sees another image
    _ok(capsys, "render", ct_store, "--out", tmp_path / "b.hevr", *argv, "-q")
    assert not np.allclose(got, _decrypt(keys, tmp_path / "b.hevr"), atol=1e-3)


def test_tf_presets_in_render_recolour_and_slice(ct_store, keys, tmp_path, capsys):
    ev = hevr.open_volume(ct_store)
    cam = Camera.orbit(ev, width=6, height=6, view="right")
    out, _ = _ok(
        capsys,
        "render",
        ct_store,
        "--out",
        tmp_path / "t.hevr",
        "--view",
        "right",
        "--size",
        "6x6",
        "--tf",
        "ct-bone",
        "--keep-sums",
        tmp_path / "t.hevrsums",
        "-q",
    )
    nodes = hevr.tf_preset("ct-bone", CT)
    assert "0.3233:#d9b38c" in out
    kw = dict(mode="tf", nodes=nodes)
    ref = hevr.render_plain(_hu(), cam, spacing=ev.spacing, value_range=CT, vector_dims=6, **kw)
    got = _decrypt(keys, tmp_path / "t.hevr", nodes=nodes)
    assert got.shape == ref.shape and np.all(np.abs(got - ref) <= hevr.error_bound(ev, cam, **kw))
    assert ref.max() > 0
    # hevr decrypt turns a preset into nodes with --value-range (a frame does not record the store's)
    err = _fails(capsys, "decrypt", tmp_path / "t.hevr", "--key", keys, "--tf", "ct-bone")
    assert err.startswith("hevr: error: --tf ct-bone: a preset needs the store's value range"), err
    _ok(
        capsys,
        "decrypt",
        tmp_path / "t.hevr",
        "--key",
        keys,
        "--tf",
        "ct-bone",
        "--value-range=-1024,3071",
        "--npy",
        tmp_path / "t.npy",
        "-q",
    )
    assert np.array_equal(np.load(tmp_path / "t.npy"), got)
    # recolour with another preset, resolved with the sums' value range
    _ok(capsys, "recolour", tmp_path / "t.hevrsums", "--out", tmp_path / "r.hevr", "--tf", "CT-Soft-Tissue", "-q")
    kw = dict(mode="tf", nodes=hevr.tf_preset("ct-soft-tissue", CT))
    ref = hevr.render_plain(_hu(), cam, spacing=ev.spacing, value_range=CT, vector_dims=6, **kw)
    assert np.all(
        np.abs(_decrypt(keys, tmp_path / "r.hevr", nodes=kw["nodes"]) - ref) <= hevr.error_bound(ev, cam, **kw)
    )
    # slice, and the node syntax still works
    _ok(capsys, "slice", ct_store, "--out", tmp_path / "s.hevr", "--axial", "3", "--tf", "ct-lung", "-q")
    _ok(
        capsys, "render", ct_store, "--out", tmp_path / "n.hevr", "--size", "4x4", "--tf", "0.279:#0000ff,0.5:red", "-q"
    )


def test_a_preset_outside_the_store_range_is_refused(tmp_path, keys, capsys):
    _ok(capsys, "encrypt", "phantom:6", "--key", keys, "--out", tmp_path / "p.zarr", "--vector-dims", "3", "-q")
    err = _fails(capsys, "render", tmp_path / "p.zarr", "--out", tmp_path / "x.hevr", "--tf", "ct-bone")
    assert err.startswith(
        "hevr: error: --tf ct-bone: the CT preset 'ct-bone' has no node inside the value range (0, 255)"
    )
    assert not (tmp_path / "x.hevr").exists()


@pytest.mark.parametrize(
    "argv, start",
    [
        (
            ["render", "{store}", "--out", "{tmp}/x.hevr", "--view", "front"],
            "argument --view: invalid choice: 'front' (choose from 'anterior', 'posterior', 'left', 'right', "
            "'superior', 'inferior')",
        ),
        (
            ["render", "{store}", "--out", "{tmp}/x.hevr", "--tf", "ct-brain"],
            "argument --tf: expected a preset (ct-bone, ct-soft-tissue, ct-lung, mr-generic) or DENSITY:COLOR",
        ),
        (
            ["encrypt", "phantom:6", "--key", "{key}", "--out", "{tmp}/x.zarr", "--modality", "XY"],
            "argument --modality: expected one of auto, CT, MR, US, got 'XY'",
        ),
        (
            ["encrypt", "phantom:6", "--key", "{key}", "--out", "{tmp}/x.zarr", "--modality", "PT"],
            "argument --modality: expected one of auto, CT, MR, US, got 'PT'; PT has no fixed value range",
        ),
        (
            ["encrypt", "phantom:6", "--key", "{key}", "--out", "{tmp}/x.zarr", "--series", "1.2"],
            "--series: expected a scan file or folder as INPUT, got 'phantom:6'",
        ),
        (
            ["encrypt", "phantom:6", "--key", "{key}", "--out", "{tmp}/x.zarr", "--oblique", "tilt"],
            "argument --oblique: invalid choice: 'tilt'",
        ),
    ],
)
def test_bad_options_exit_2(ct_store, keys, tmp_path, capsys, argv, start):
    filled = [a.format(store=ct_store, tmp=tmp_path, key=keys) for a in argv]
    err = _fails(capsys, *filled)
    assert err.startswith(f"hevr: error: {start}"), err
    assert not (tmp_path / "x.hevr").exists() and not (tmp_path / "x.zarr").exists()


def test_dicom_options_need_a_dicom_input(tmp_path, keys, capsys):
    src = _write_nifti(tmp_path / "ct.nii.gz", _hu())
    err = _fails(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "x.zarr", "--series", "1.2")
    assert err.startswith("hevr: error: --series"), err
    err = _fails(capsys, "encrypt", src, "--key", keys, "--out", tmp_path / "x.zarr", "--volume", "1")
    assert err.startswith("hevr: error: --volume:"), err


# -- DICOM folders with several series ------------------------------------------------------------
def test_info_lists_series_and_encrypt_picks_one(tmp_path, keys, capsys):
    folder = tmp_path / "study"
    hu = _hu()
    _write_dicom(folder, hu, series="1.2.826.0.1.3680043.2.111", number=3)
    _write_dicom(folder, hu[:, :, ::-1] // 2, series="1.2.826.0.1.3680043.2.222", number=4)
    out, _ = _ok(capsys, "info", folder)
    assert "DICOM folder, 2 series" in out
    series_rows = [line for line in out.splitlines() if line.startswith("series:")]
    assert len(series_rows) == 2
    assert "1.2.826.0.1.3680043.2.111" in series_rows[0] and "#3 CT 'series 3'" in series_rows[0]
    assert "5 images" in series_rows[1]
    err = _fails(capsys, "encrypt", folder, "--key", keys, "--out", tmp_path / "x.zarr")
    assert "found 2" in err and "--series UID" in err
    assert "1.2.826.0.1.3680043.2.111" in err and "1.2.826.0.1.3680043.2.222" in err
    assert "CLI" not in err and "series=UID" not in err
    out, _ = _ok(
        capsys,
        "encrypt",
        folder,
        "--key",
        keys,
        "--out",
        tmp_path / "b.zarr",
        "--series",
        "4",
        "--vector-dims",
        "3",
        "-q",
    )
    ev = hevr.open_volume(tmp_path / "b.zarr")
    assert ev.value_range == CT and ev.shape == hu.shape
    # one series: info describes the scan as well
    out, _ = _ok(capsys, "info", _write_dicom(tmp_path / "one", hu))
    assert "DICOM folder, 1 series" in out and "modality: CT" in out
    assert "density range -1024 .. 3071 by default (the CT range" in out


def test_help_texts(capsys):
    assert main(["render", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--view VIEW" in out and "anterior" in out and "ct-bone" in out
    assert main(["encrypt", "--help"]) == 0
    out = capsys.readouterr().out
    for flag in ("--modality", "--series UID", "--volume INDEX", "--allow-uneven", "--oblique"):
        assert flag in out, flag
    assert main(["info", "--help"]) == 0
    assert "DICOM folder" in capsys.readouterr().out


# -- the patient frame travels to the store ---------------------------------------------------------
def test_the_store_records_the_scans_frame_and_origin(ct_store, keys, tmp_path, capsys):
    ev = hevr.open_volume(ct_store)
    scan = hevr.read_scan(ct_store.parent / "ct.nii.gz")
    assert ev.frame == "RAS" and scan.frame == "RAS" and ev.patient_origin == scan.origin
    out, _ = _ok(capsys, "info", ct_store)
    assert "RAS+, voxel (0, 0, 0) at" in out
    # a phantom has no orientation: the store says so, and --view warns that it assumes RAS+
    _ok(capsys, "encrypt", "phantom:6", "--key", keys, "--out", tmp_path / "p.zarr", "--brick", "3", "-q")
    assert hevr.open_volume(tmp_path / "p.zarr").frame is None
    out, _ = _ok(capsys, "info", tmp_path / "p.zarr")
    assert "none recorded" in out
    _, err = _ok(
        capsys, "render", tmp_path / "p.zarr", "--out", tmp_path / "p.hevr", "--view", "anterior", "--size", "4x4", "-q"
    )
    assert "records no patient frame" in err
    _, err = _ok(capsys, "render", ct_store, "--out", tmp_path / "c.hevr", "--view", "anterior", "--size", "4x4", "-q")
    assert "records no patient frame" not in err


def test_encrypt_volume_takes_a_scan(tmp_path, keys):
    import nibabel as nib

    vol = np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6)
    affine = np.diag([-0.5, 2.0, 1.5, 1.0])  # LAS, 0.5 x 2 x 1.5 mm
    affine[:3, 3] = (10.0, -20.0, 30.0)
    nib.save(nib.Nifti1Image(vol.transpose(2, 1, 0), affine), tmp_path / "s.nii")
    scan = hevr.read_scan(tmp_path / "s.nii")
    ev = hevr.encrypt_volume(scan, tmp_path / "s.zarr", hevr.load_key(keys), brick=3, progress=False)
    assert ev.spacing == (0.5, 2.0, 1.5) and ev.frame == "RAS"
    assert ev.patient_origin == (10.0 - 0.5 * 5, -20.0, 30.0)  # x flipped: voxel 0 is the file's last column
    priv = hevr.load_key(keys)
    assert [priv.decrypt(c) for c in ev.read_brick((0, 0, 0))][:3] == list(vol[0, 0, ::-1][:3])
    ev2 = hevr.encrypt_volume(scan, tmp_path / "t.zarr", priv, spacing=(1, 1, 1), brick=3, progress=False)
    assert ev2.spacing == (1.0, 1.0, 1.0) and ev2.frame == "RAS"  # spacing= still overrides


# -- a single 2-D slice is not a volume (issue 29, item 1) ------------------------------------------
@pytest.mark.filterwarnings("ignore:Expected explicit VR")  # from siblings read for CT_small's series
def test_a_single_dicom_slice_is_described_and_refused(tmp_path, capsys):
    """pydicom's CT_small.dcm (one 128x128 slice): ``info`` says encrypt refuses it, ``encrypt``
    refuses it in well under a second with one line naming INPUT, and writes nothing."""
    pytest.importorskip("pydicom")
    import time

    from pydicom.data import get_testdata_file

    ct = get_testdata_file("CT_small.dcm", download=False)
    assert main(["keygen", "--bits", "256", "--out", str(tmp_path / "key.json"), "-q"]) == 0
    out, _ = _ok(capsys, "info", ct)
    assert "128×128×1 voxels" in out and "refused: a single slice" in out
    t0 = time.perf_counter()
    err = _fails(capsys, "encrypt", ct, "--key", tmp_path / "key.json", "--out", tmp_path / "ct.zarr")
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "ct.zarr").exists()
    assert (
        err.startswith("hevr: error: INPUT: expected a volume at least 2 voxels thick along every axis")
        and "got 1 slice of 128x128 voxels" in err
    ), err


def test_a_single_slice_scan_is_refused_and_a_frame_that_misses_says_so(tmp_path, keypair256, caplog):
    slice_ = hevr.Scan(volume=np.zeros((1, 6, 7), np.uint8), spacing=(1.0, 1.0, 1.0), source="one.tif")
    with pytest.raises(
        hevr.ParameterError,
        match=r"^vol: expected a volume at least 2 voxels thick .* got "
        r"1 slice of 7x6 voxels \(shape \(1, 6, 7\)\)",
    ):
        hevr.encrypt_volume(slice_, tmp_path / "s.zarr", keypair256[1], progress=False)
    flat = hevr.Scan(volume=np.zeros((5, 1, 7), np.uint8), spacing=(1.0, 1.0, 1.0), source="flat.nii")
    with pytest.raises(hevr.ParameterError, match=r"got 7x1x5 voxels"):
        hevr.encrypt_volume(flat, tmp_path / "s.zarr", keypair256[1], progress=False)
    assert not (tmp_path / "s.zarr").exists()
    ev = hevr.encrypt_volume(np.ones((4, 5, 6), np.uint8), tmp_path / "v.zarr", keypair256[1], progress=False)
    away = Camera(position=(50.0, 50.0, 50.0), focal_point=(100.0, 100.0, 100.0), width=8, height=8)
    with caplog.at_level("WARNING", logger="hevr"):
        img = hevr.render(ev, away, progress=False)
    assert img.n_ciphertexts == 0 and "no ray of this 8x8 camera hits the volume" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="hevr"):
        hevr.render(ev, Camera.orbit(ev, width=8, height=8), progress=False)
    assert "hits the volume" not in caplog.text


# -- NaN voxels (issue 29, item 5) ---------------------------------------------------------------------------
def test_nan_voxels_are_counted_refused_and_filled_on_request(tmp_path, keys, capsys):
    """A float NIfTI written by nibabel with NaN voxels: ``info`` counts them and names --nan-as;
    ``encrypt`` refuses with one line naming --nan-as; ``--nan-as 0`` encrypts them as 0."""
    nib = pytest.importorskip("nibabel")
    vol = np.linspace(0, 1, 4 * 5 * 6, dtype=np.float32).reshape(4, 5, 6)
    vol[1, 2, 3] = vol[2, 0, 0] = np.nan
    path = tmp_path / "pet.nii.gz"
    nib.save(nib.Nifti1Image(vol.transpose(2, 1, 0), np.eye(4)), str(path))
    out, _ = _ok(capsys, "info", path)
    assert "and 2 NaN voxels of 120" in out and "needs --nan-as VALUE" in out and "nan .. nan" not in out
    err = _fails(capsys, "encrypt", path, "--key", keys, "--out", tmp_path / "v.zarr")
    assert (
        "got 2 NaN voxels of 120; give them a value with --nan-as VALUE" in err and not (tmp_path / "v.zarr").exists()
    )
    out, _ = _ok(capsys, "encrypt", path, "--key", keys, "--out", tmp_path / "v.zarr", "--nan-as", "0")
    assert "2 NaN voxels of 120 encrypted as 0 (--nan-as)" in out
    ev = hevr.open_volume(tmp_path / "v.zarr")
    priv = hevr.load_key(keys)
    got = (
        np.array([priv.decrypt(c) for c in ev.read_brick((0, 0, 0))], dtype=np.float64) * 10.0**ev.meta.scalar.exponent
    )
    want = np.nan_to_num(hevr.read_scan(path).volume, nan=0.0)[: ev.brick[0], : ev.brick[1], : ev.brick[2]]
    assert np.allclose(got, want.ravel(), atol=10.0**ev.meta.scalar.exponent)
    with pytest.raises(hevr.ParameterError, match=r"np.nan_to_num\(vol, nan=VALUE\); hevr encrypt --nan-as VALUE"):
        hevr.encrypt_volume(vol, tmp_path / "w.zarr", priv, progress=False)


# -- info reads what encrypt reads (issue 29, item 4) ----------------------------------------------------
def test_info_takes_the_options_that_encrypt_reads_with(tmp_path, capsys):
    """``hevr info`` takes --series, --volume, --allow-uneven and --oblique as ``hevr encrypt`` does,
    so a 4-D NIfTI (nibabel) and one series of a folder are described, not refused."""
    nib = pytest.importorskip("nibabel")
    four = np.arange(3 * 4 * 5 * 2, dtype=np.int16).reshape(5, 4, 3, 2)  # x, y, z, t
    nib.save(nib.Nifti1Image(four, np.eye(4)), str(tmp_path / "fmri.nii.gz"))
    _fails(capsys, "info", tmp_path / "fmri.nii.gz")  # which volume? (as encrypt without --volume)
    out, _ = _ok(capsys, "info", tmp_path / "fmri.nii.gz", "--volume", "1")
    assert "5×4×3 voxels" in out and "int16" in out
    folder = tmp_path / "study"
    hu = _hu()
    _write_dicom(folder, hu, series="1.2.826.0.1.3680043.2.111", number=3)
    _write_dicom(folder, hu[:, :, ::-1] // 2, series="1.2.826.0.1.3680043.2.222", number=4)
    out, _ = _ok(capsys, "info", folder, "--series", "4")
    assert "DICOM folder" not in out and f"{hu.shape[2]}×{hu.shape[1]}×{hu.shape[0]} voxels" in out
    assert "modality: CT" in out


# -- exit status of a missing decoder (issue 29, item 7) -------------------------------------------------
@pytest.mark.filterwarnings("ignore:Expected explicit VR")
def test_a_missing_decoder_plugin_is_a_missing_dependency(tmp_path, keys, capsys):
    """pydicom's JPEG-LS file without a JPEG-LS plugin: exit 1 (a missing optional dependency, as
    the help says), naming the plugins that would decode it."""
    pydicom = pytest.importorskip("pydicom")
    from pydicom.data import get_testdata_file

    src = get_testdata_file("MR_small_jpeg_ls_lossless.dcm", download=False)
    try:
        _ = pydicom.dcmread(src).pixel_array  # decoding is the point: it fails without a plugin
    except RuntimeError:
        pass
    else:
        pytest.skip("a JPEG-LS plugin is installed here")
    folder = tmp_path / "jls"
    folder.mkdir()
    (folder / "mr.dcm").write_bytes(Path(src).read_bytes())  # alone: no sibling of another syntax
    code, _, err = _run(capsys, "encrypt", folder / "mr.dcm", "--key", keys, "--out", tmp_path / "x.zarr")
    assert code == 1, (code, err)
    assert "needs a pydicom plugin that is not installed" in err and "pylibjpeg" in err and err.count("\n") == 1


@pytest.mark.parametrize("kind", ["dicom", "nrrd", "nifti"])
def test_corrupt_pixel_data_exits_1(tmp_path, keys, capsys, kind):
    """A readable header whose data fails (cut short, or not decodable) is failed data: exit 1 and
    one line naming the file, as the help says; before, exit 2 (issue 29, item 7)."""
    if kind == "dicom":
        pytest.importorskip("pydicom")
        from pydicom.data import get_testdata_file

        path = tmp_path / "mr.dcm"
        path.write_bytes(Path(get_testdata_file("MR_small.dcm", download=False)).read_bytes()[:-3000])
        words = "mr.dcm: cannot decode the pixel data"
    elif kind == "nrrd":
        path = tmp_path / "v.nrrd"
        hevr.save_volume(path, np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6), spacing=(1, 1, 1))
        path.write_bytes(path.read_bytes()[:-10])
        words = "v.nrrd: truncated"
    else:
        nib = pytest.importorskip("nibabel")
        path = tmp_path / "v.nii"
        nib.save(nib.Nifti1Image(np.arange(4 * 5 * 6, dtype=np.int16).reshape(6, 5, 4), np.eye(4)), path)
        path.write_bytes(path.read_bytes()[:-10])
        words = "v.nii: truncated"
    for argv in (("info", path), ("encrypt", path, "--key", keys, "--out", tmp_path / "x.zarr")):
        code, _, err = _run(capsys, *argv)
        assert code == 1 and words in err and err.count("\n") == 1, (argv[0], code, err)
    assert not (tmp_path / "x.zarr").exists()


def test_info_of_an_uneven_series_names_the_option(tmp_path, capsys):
    """A series with a missing slice: ``hevr info`` says --allow-uneven (not allow_uneven=True) and
    describes the scan with it (issue 29, items 4 and 7)."""
    folder = _write_dicom(tmp_path / "gap", _hu())
    (sorted(folder.glob("*.dcm"))[2]).unlink()  # a missing slice: 1.5 mm steps with one of 3 mm
    code, _, err = _run(capsys, "info", folder)
    assert code == 2 and "--allow-uneven" in err and "allow_uneven=True" not in err, err
    out, _ = _ok(capsys, "info", folder, "--allow-uneven")
    assert "7×6×4 voxels" in out


def test_info_of_a_dicomdir_lists_its_series(capsys):
    """pydicom's DICOMDIR (13 series): one row per series, as for a folder (issue 29, item 4)."""
    pytest.importorskip("pydicom")
    from pydicom.data import get_testdata_file

    out, _ = _ok(capsys, "info", get_testdata_file("DICOMDIR", download=False))
    series = [line for line in out.splitlines() if line.startswith("series:")]
    assert "DICOMDIR, 13 series" in out and len(series) == 13 and "Routine Brain" in out
