"""One patient, four files, one picture: the end-to-end test of hevr's RAS+ patient frame.

An asymmetric phantom, a bright blob near the patient's right-anterior-superior corner and a
dimmer one at the left-posterior side, is saved by the formats' own libraries as

(a) NIfTI with an RAS affine (nibabel),
(b) NIfTI with an LAS affine, the data flipped along i to match (nibabel),
(c) an LPS NRRD (pynrrd): i runs to the patient's left, j to the back,
(d) a DICOM axial series (pydicom): columns to the left, rows to the back (LPS), slices upwards.

:func:`hevr.read_scan` must return the same RAS+ volume, spacing and origin for all four.
One of them is encrypted and rendered from the front (``view="anterior"``): the decrypted
image matches :func:`hevr.render_plain` within :func:`hevr.error_bound`, and the bright blob
is in the image's upper-left quarter (radiology: the patient's right on the viewer's left,
superior up). The plaintext renders of all four in the anterior and left views are identical.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from test_dicom import write_series

import hevr
from hevr.errors import InsecureKeyWarning

nib = pytest.importorskip("nibabel")
nrrd = pytest.importorskip("nrrd")
pytest.importorskip("pydicom")

N = 12
SPACING = (0.5, 0.75, 1.25)  # (sx, sy, sz), exact in binary: the four files agree to the bit
ORIGIN = (10.0, -20.0, 30.0)  # RAS+ mm of voxel (0, 0, 0)
BRIGHT, DIM = 1000, 300


def phantom() -> np.ndarray:
    """(z, y, x) in RAS+: x to the patient's right, y anterior, z superior."""
    vol = np.zeros((N, N, N), np.int16)
    vol[8:11, 8:11, 8:11] = BRIGHT  # high x, y, z: right, anterior, superior
    vol[4:7, 1:4, 1:4] = DIM  # low x, y: left, posterior
    return vol


def _affine(flip_i: bool) -> np.ndarray:
    a = np.diag([*SPACING, 1.0])
    a[:3, 3] = ORIGIN
    if flip_i:  # LAS: i runs to the left, from the right-most voxel
        a[0, 0], a[0, 3] = -SPACING[0], ORIGIN[0] + (N - 1) * SPACING[0]
    return a


def write_all(folder: Path, ras: np.ndarray) -> dict[str, Path]:
    """The four files of ``ras`` (see the module docstring)."""
    paths = {
        "nifti-ras": folder / "ras.nii",
        "nifti-las": folder / "las.nii.gz",
        "nrrd-lps": folder / "lps.nrrd",
        "dicom": folder / "dicom",
    }
    nib.save(nib.Nifti1Image(ras.transpose(2, 1, 0), _affine(False)), paths["nifti-ras"])
    nib.save(nib.Nifti1Image(ras[:, :, ::-1].transpose(2, 1, 0), _affine(True)), paths["nifti-las"])
    # LPS: +x_LPS is the patient's left, +y_LPS posterior; file voxel (i, j) = RAS voxel (N-1-i, N-1-j),
    # whose LPS position is (-(x0 + (N-1) sx), -(y0 + (N-1) sy), z0) for i = j = 0.
    lps_origin = (-(ORIGIN[0] + (N - 1) * SPACING[0]), -(ORIGIN[1] + (N - 1) * SPACING[1]), ORIGIN[2])
    lps = ras[:, ::-1, ::-1]
    nrrd.write(
        str(paths["nrrd-lps"]),
        np.ascontiguousarray(lps),
        index_order="C",
        header={
            "space": "left-posterior-superior",
            "space directions": np.diag(SPACING),
            "space origin": np.array(lps_origin),
            "encoding": "raw",
            "kinds": ["domain"] * 3,
        },
    )
    # Axial DICOM: IOP (1,0,0, 0,1,0) = columns along +x_LPS, rows along +y_LPS; the same layout
    # as the NRRD. PixelSpacing is (between rows, between columns) = (sy, sx). Stored values
    # + RescaleIntercept -1024 give the phantom back.
    write_series(
        paths["dicom"],
        (lps + 1024).astype(np.int16),
        origin=lps_origin,
        gap=SPACING[2],
        spacing=(SPACING[1], SPACING[0]),
        intercept=-1024,
    )
    return paths


@pytest.fixture(scope="module")
def scans(tmp_path_factory: pytest.TempPathFactory) -> dict[str, hevr.Scan]:
    paths = write_all(tmp_path_factory.mktemp("views"), phantom())
    return {name: hevr.read_scan(path) for name, path in paths.items()}


def test_the_four_files_load_to_one_ras_volume(scans: dict[str, hevr.Scan]) -> None:
    ras = phantom()
    for name, scan in scans.items():
        assert scan.frame == "RAS", name
        np.testing.assert_array_equal(scan.volume, ras, err_msg=name)
        assert scan.spacing == SPACING, name
        assert scan.origin == pytest.approx(ORIGIN, abs=1e-6), name
    # the bright blob is at the patient's right (high x), anterior (high y), superior (high z)
    z, y, x = np.argwhere(scans["dicom"].volume == BRIGHT).mean(axis=0)
    assert x > N / 2 and y > N / 2 and z > N / 2
    assert scans["nifti-ras"].modality is None and scans["dicom"].modality == "CT"
    assert isinstance(scans["nifti-ras"].volume, np.memmap)  # .nii and raw NRRD stay mapped
    assert isinstance(scans["nrrd-lps"].volume, np.memmap)


def _camera(scan: hevr.Scan, view: str) -> hevr.Camera:
    return hevr.Camera.orbit(scan.volume.shape, spacing=scan.spacing, view=view, width=16, height=16)


@pytest.mark.parametrize("view", ["anterior", "left"])
def test_plaintext_renders_of_the_four_are_identical(scans: dict[str, hevr.Scan], view: str) -> None:
    images = {
        name: hevr.render_plain(np.asarray(s.volume), _camera(s, view), mode="xray", spacing=s.spacing)
        for name, s in scans.items()
    }
    first = images["nifti-ras"]
    assert first.max() > 0
    for name, img in images.items():
        np.testing.assert_array_equal(img, first, err_msg=f"{name}, view {view}")


def _bright_pixels(scan: hevr.Scan, view: str) -> np.ndarray:
    """(row, col) of the pixels that see the bright blob, from a render of the blob alone."""
    only = np.where(np.asarray(scan.volume) == BRIGHT, 1, 0).astype(np.int16)
    img = hevr.render_plain(only, _camera(scan, view), mode="xray", spacing=scan.spacing)
    return np.argwhere(img > 0.5 * img.max())


def test_left_view_puts_anterior_on_the_left(scans: dict[str, hevr.Scan]) -> None:
    rows, cols = _bright_pixels(scans["nrrd-lps"], "left").T
    assert cols.max() < 8 and rows.max() < 8  # anterior on the image's left, superior up


def test_encrypted_anterior_view(scans: dict[str, hevr.Scan], keypair256, tmp_path: Path) -> None:
    pub, priv = keypair256
    scan = scans["dicom"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        ev = hevr.encrypt_volume(scan, tmp_path / "ct.zarr", pub, brick=6, progress=False)
    assert ev.spacing == pytest.approx(SPACING) and ev.frame == "RAS"
    cam = hevr.Camera.orbit(ev, view="anterior", width=16, height=16)
    got = hevr.render(ev, cam, mode="xray", progress=False).decrypt(priv)
    ref = hevr.render_plain(np.asarray(scan.volume), cam, mode="xray", spacing=scan.spacing)
    bound = hevr.error_bound(ev, cam, mode="xray")
    assert got.shape == ref.shape == (16, 16)
    assert np.all(np.abs(got - ref) <= bound), np.abs(got - ref).max()
    assert ref.max() > 10 * bound.max()  # the comparison means something
    rows, cols = _bright_pixels(scan, "anterior").T
    assert len(rows) > 0
    assert cols.max() < 8, cols  # the patient's right on the viewer's left
    assert rows.max() < 8, rows  # superior up
    # and the decrypted image shows it there too: more signal in the upper-left quarter
    assert got[:8, :8].sum() > got[:8, 8:].sum() and got[:8, :8].sum() > got[8:, :8].sum()
