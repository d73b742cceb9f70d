"""EncryptedImage: decryption with the right key only, save/load, PNG windowing."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import hevr
from hevr.image.display import to_uint8


@pytest.fixture(scope="module")
def frame(tmp_path_factory, keypair256):
    rng = np.random.default_rng(1)
    vol = rng.integers(0, 256, (5, 6, 7)).astype(np.uint8)
    ev = hevr.encrypt_volume(
        vol, tmp_path_factory.mktemp("i") / "v.zarr", keypair256[1], brick=3, vector_dims=2, progress=False
    )
    cam = hevr.Camera.orbit(ev, azimuth=10, width=9, height=8)
    return hevr.render(ev, cam, mode="tf", nodes=[(0.2, "red"), (0.8, "blue")], progress=False)


def test_key_mismatch(frame, keypair512):
    with pytest.raises(hevr.KeyMismatchError, match="fingerprint"):
        frame.decrypt(keypair512[1])


def test_save_load_round_trip(tmp_path, frame, keypair256):
    path = tmp_path / "f.hevr"
    frame.save(path)
    back = hevr.load_image(path)
    assert frame.shape == (8, 9, 3) and back.shape == (8, 9)  # the file does not say it is a transfer function
    assert back.exponent == frame.exponent and back.fingerprint == frame.fingerprint
    # the transfer function is not in the file: the client gives it again
    assert np.array_equal(
        back.decrypt(keypair256[1], nodes=[(0.2, "red"), (0.8, "blue")]), frame.decrypt(keypair256[1])
    )
    # compact: header + ciphertext bytes only
    w = keypair256[0].ciphertext_bytes
    assert path.stat().st_size < frame.n_ciphertexts * w + 4096


def test_truncated_and_foreign_files(tmp_path, frame):
    path = tmp_path / "f.hevr"
    frame.save(path)
    path.write_bytes(path.read_bytes()[:-3])
    with pytest.raises(hevr.IntegrityError, match="checksum mismatch"):
        hevr.load_image(path)
    path.write_bytes(path.read_bytes()[:20])
    with pytest.raises(hevr.CorruptStoreError, match="truncated"):
        hevr.load_image(path)
    (tmp_path / "x.hevr").write_bytes(b"PNG....")
    with pytest.raises(hevr.CorruptStoreError, match="magic"):
        hevr.load_image(tmp_path / "x.hevr")


def test_png_windowing(tmp_path):
    grey = np.linspace(0, 200, 20).reshape(4, 5)
    hevr.save_png(grey, tmp_path / "g.png")
    g = np.asarray(Image.open(tmp_path / "g.png"))
    assert g.dtype == np.uint8 and g.shape == (4, 5) and g.max() == 255 and g.min() == 0
    rgb = np.zeros((3, 3, 3))
    rgb[0, 0] = (0.5, 0.25, 0.0)
    out = to_uint8(rgb)
    assert tuple(out[0, 0]) == (255, 128, 0)  # joint windowing keeps colour ratios
    with pytest.raises(hevr.ParameterError):
        to_uint8(np.zeros((2, 2, 4)))


def test_decrypt_needs_a_private_key(frame, keypair256):
    with pytest.raises(hevr.ParameterError, match="PrivateKey"):
        frame.decrypt(keypair256[0])


# -- slices shown the way radiology viewers show them (issue 39, item 6) ----------------------
def _ras_volume() -> np.ndarray:
    """An asymmetric (z, y, x) volume: value 100·k + 10·j + i grows to superior, anterior, right."""
    k, j, i = np.meshgrid(np.arange(6), np.arange(7), np.arange(8), indexing="ij")
    return (100 * k + 10 * j + i).astype(np.float64)


@pytest.mark.parametrize(
    "kind, index, top, left",
    [("axial", 2, "anterior", "right"), ("coronal", 3, "superior", "right"), ("sagittal", 4, "superior", "anterior")],
)
def test_save_png_turns_slices_the_radiological_way(tmp_path, kind, index, top, left):
    from hevr.rendering.reference.plain import render_slice_plain

    vol = _ras_volume()
    plane = getattr(hevr.Plane, kind)(vol.shape, index)
    raw = render_slice_plain(vol, plane)
    hevr.save_png(raw, tmp_path / "s.png", plane=plane)
    png = np.asarray(Image.open(tmp_path / "s.png")).astype(float)
    axis_of = {"superior": 0, "anterior": 1, "right": 2}
    # the top row lies further towards `top` than the bottom row, the left column further towards `left`
    assert png[0].mean() > png[-1].mean() + 20, (kind, png)
    assert png[:, 0].mean() > png[:, -1].mean(), (kind, png)
    shown = hevr.image.orient_slice(raw, plane)
    k, j, i = np.meshgrid(*map(np.arange, vol.shape), indexing="ij")
    grid = (k, j, i)
    cut = {
        "axial": (index, slice(None), slice(None)),
        "coronal": (slice(None), index, slice(None)),
        "sagittal": (slice(None), slice(None), index),
    }[kind]
    coords = {
        a: hevr.image.orient_slice(render_slice_plain(grid[ax].astype(float), plane), plane)
        for a, ax in axis_of.items()
    }
    assert (np.diff(coords[top], axis=0) < 0).all() and (np.diff(coords[left], axis=1) < 0).all()
    assert np.array_equal(np.sort(shown, axis=None), np.sort(vol[cut], axis=None))
    lay = hevr.image.slice_layout(plane)
    assert lay["kind"] == kind and lay["top"] == top.replace("right", "the patient's right")


def test_orient_slice_conventions_and_bad_input():
    vol = _ras_volume()
    plane = hevr.Plane.axial(vol.shape, 1)
    radio = hevr.image.orient_slice(vol[1], plane)
    neuro = hevr.image.orient_slice(vol[1], plane, "neurological")
    assert np.array_equal(radio, neuro[:, ::-1]) and radio[0, 0] == vol[1, -1, -1]
    assert hevr.image.slice_layout(plane.to_dict())["left"] == "the patient's right"  # a frame's info["camera"]
    oblique = hevr.Plane.oblique(vol.shape, None, (0.1, 1, 0.2), width=5, height=5)
    assert (
        hevr.image.slice_layout(oblique)["kind"] == "coronal" and hevr.image.slice_layout(oblique)["top"] == "superior"
    )
    with pytest.raises(hevr.ParameterError, match="convention: expected one of radiological, neurological"):
        hevr.image.orient_slice(vol[1], plane, "upside-down")
    with pytest.raises(hevr.ParameterError, match="plane: expected a hevr.Plane"):
        hevr.save_png(vol[1], "never.png", plane=hevr.Camera.orbit(vol.shape))


def test_default_window_shows_negative_valued_images():
    """Issue 39, item 7: a CT X-ray (air -1000, an object above it) is not black by default."""
    from hevr.image.display import default_window

    xray = np.full((8, 8), -1000.0)
    xray[2:6, 2:6] = np.linspace(-885.0, 29.5, 16).reshape(4, 4)
    img = to_uint8(xray)
    assert img[2:6, 2:6].min() > img[0, 0] and img[0, 0] == 0 and img.max() >= 250
    lo, hi = default_window(xray)
    assert lo == -1000.0 and 20 < hi <= 29.5
    hits = np.ones((8, 8), bool)
    hits[0] = False  # a ray that misses: 0, black, and out of the statistics
    xray[0] = 0.0
    assert default_window(xray, hits)[1] <= 29.5 and (to_uint8(xray, hits=hits)[0] == 0).all()
    mri = np.array([[0.0, 10.0], [20.0, 30.0]])
    assert default_window(mri)[0] == 0.0 and to_uint8(mri)[0, 0] == 0  # positive images: as before
    with pytest.raises(hevr.ParameterError, match=r"hits: expected a mask of shape \(8, 8\)"):
        to_uint8(xray, hits=np.ones((2, 2), bool))
