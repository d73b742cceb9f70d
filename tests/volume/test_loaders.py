"""Tests for hevr.volume.loaders (read_scan / load_volume / save_volume) and the NRRD reader in hevr.volume.nrrd."""

from __future__ import annotations

import gzip
import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest

from hevr.errors import (
    HevrError,
    MissingDependencyError,
    ParameterError,
    VolumeFormatError,
)
from hevr.volume.loaders import _format, load_volume, read_scan, save_volume

DATA = Path(__file__).resolve().parents[1] / "data"  # shipped with the tests (tests/data/README.md)
TOOTH_SHA512 = "5ee3d77ae951e129d29062a4fd4d8730fd8670bd"


def _volume(dtype: str | type, shape: tuple[int, int, int] = (5, 6, 7)) -> np.ndarray:
    """A deterministic volume using most of the dtype's range, no two axes alike."""
    dt = np.dtype(dtype)
    ramp = np.arange(np.prod(shape), dtype=np.float64).reshape(shape)
    if dt.kind == "f":
        return (ramp * 0.37 - 11.5).astype(dt)
    info = np.iinfo(dt)
    return (info.min + (ramp * 7919) % (float(info.max) - info.min + 1)).astype(dt)


def _check(vol: np.ndarray, expected: np.ndarray) -> None:
    assert vol.shape == expected.shape
    assert vol.dtype == expected.dtype.newbyteorder("=")
    assert vol.dtype.isnative
    np.testing.assert_array_equal(vol, expected)


def _nrrd_header(**fields: str) -> str:
    base = {"type": "uint8", "dimension": "3", "sizes": "4 3 2", "encoding": "raw"}
    base.update({k.replace("_", " "): v for k, v in fields.items()})
    return "NRRD0004\n" + "".join(f"{k}: {v}\n" for k, v in base.items() if v is not None)


# ----------------------------------------------------------------------------- tooth CT


@pytest.mark.parametrize("name", ["tooth.nhdr", "tooth_103x94x161_uint8.raw"])
def test_tooth(name: str) -> None:
    vol, spacing = load_volume(DATA / name)
    assert vol.shape == (161, 94, 103)
    assert vol.dtype == np.uint8
    assert spacing == (1.0, 1.0, 1.0)
    assert isinstance(vol, np.memmap)  # mapped, not read into memory up front
    if name == "tooth.nhdr":
        # space: left-posterior-superior with identity directions: i runs to the patient's left and
        # j to the back, so in RAS+ the x and y axes come back reversed (views of the same map).
        vol = vol[:, ::-1, ::-1]
    digest = hashlib.sha512(np.ascontiguousarray(vol).tobytes()).hexdigest()
    assert digest.startswith(TOOTH_SHA512)
    # The volume is what the raw file holds, x fastest.
    assert digest == hashlib.sha512((DATA / "tooth_103x94x161_uint8.raw").read_bytes()).hexdigest()


def test_tooth_scan_geometry() -> None:
    scan = read_scan(DATA / "tooth.nhdr")
    assert scan.frame == "RAS" and scan.modality is None and scan.source.endswith("tooth.nhdr")
    # space origin (-51.5, -47, -80.5) LPS is voxel (0, 0, 0) of the file; RAS+ voxel (0, 0, 0) is the
    # file's (102, 93, 0): LPS (50.5, 46, -80.5) = RAS (-50.5, -46, -80.5).
    assert scan.origin == (-50.5, -46.0, -80.5)
    assert scan.details["space"] == "left-posterior-superior"
    raw = read_scan(DATA / "tooth_103x94x161_uint8.raw")
    assert raw.frame is None and raw.origin == (0.0, 0.0, 0.0)
    np.testing.assert_array_equal(scan.volume, raw.volume[:, ::-1, ::-1])


def test_tooth_with_str_path_and_spacing_override() -> None:
    vol, spacing = load_volume(str(DATA / "tooth.nhdr"), spacing=(0.5, 0.5, 2))
    assert vol.shape == (161, 94, 103)
    assert spacing == (0.5, 0.5, 2.0)


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("dtype", ["uint8", "int16", "uint16", "int32", "float32", "float64"])
def test_npy_round_trip(tmp_path: Path, dtype: str) -> None:
    arr = _volume(dtype)
    path = save_volume(tmp_path / "v.npy", arr)
    vol, spacing = load_volume(path)
    _check(vol, arr)
    assert spacing == (1.0, 1.0, 1.0)


def test_npy_big_endian_and_fortran_order(tmp_path: Path) -> None:
    arr = _volume("int16")
    np.save(tmp_path / "be.npy", arr.astype(">i2"))
    np.save(tmp_path / "f.npy", np.asfortranarray(arr))
    for name in ("be.npy", "f.npy"):
        vol, _ = load_volume(tmp_path / name, spacing=[1, 2, 3])
        _check(vol, arr)


@pytest.mark.parametrize("dtype", ["int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"])
def test_raw_round_trip_by_name(tmp_path: Path, dtype: str) -> None:
    arr = _volume(dtype, (3, 4, 5))
    # The name lists the sizes x, y, z; the array shape is (z, y, x).
    path = save_volume(tmp_path / f"scan_5x4x3_{dtype}.raw", arr)
    vol, spacing = load_volume(path)
    _check(vol, arr)
    assert spacing == (1.0, 1.0, 1.0)


@pytest.mark.parametrize("byte_order", ["little", "big"])
def test_raw_round_trip_with_kwargs(tmp_path: Path, byte_order: str) -> None:
    arr = _volume("int16", (4, 3, 2))
    path = save_volume(tmp_path / "plain.raw", arr, byte_order=byte_order)
    assert path.stat().st_size == arr.nbytes
    assert path.read_bytes() == arr.astype("<i2" if byte_order == "little" else ">i2").tobytes()
    vol, spacing = load_volume(path, shape=(4, 3, 2), dtype=np.int16, byte_order=byte_order, spacing=(0.25, 0.5, 4.0))
    _check(vol, arr)
    assert spacing == (0.25, 0.5, 4.0)


def test_raw_kwargs_override_the_name(tmp_path: Path) -> None:
    arr = _volume("uint16", (2, 3, 4))
    path = tmp_path / "misnamed_9x9x9_uint8.raw"
    path.write_bytes(arr.astype("<u2").tobytes())
    vol, _ = load_volume(path, shape=(2, 3, 4), dtype="uint16")
    _check(vol, arr)


@pytest.mark.parametrize("suffix", [".nhdr", ".nrrd"])
@pytest.mark.parametrize("encoding", ["raw", "gzip"])
@pytest.mark.parametrize("byte_order", ["little", "big"])
@pytest.mark.parametrize("dtype", ["uint8", "int16", "float32"])
def test_nrrd_round_trip(tmp_path: Path, suffix: str, encoding: str, byte_order: str, dtype: str) -> None:
    arr = _volume(dtype)
    spacing = (0.5, 1.25, 3.0)  # anisotropic, so a mix-up of axis order would show
    path = save_volume(tmp_path / f"v{suffix}", arr, spacing, encoding=encoding, byte_order=byte_order)
    vol, got = load_volume(path)
    _check(vol, arr)
    assert got == spacing
    if suffix == ".nhdr":
        data = tmp_path / ("v.raw.gz" if encoding == "gzip" else "v.raw")
        assert data.is_file()
        assert f"data file: {data.name}" in path.read_text()


def test_nhdr_writes_loadable_big_endian_int16(tmp_path: Path) -> None:
    arr = _volume("int16", (3, 4, 5))
    path = save_volume(tmp_path / "be.nhdr", arr, (2, 1, 0.5), byte_order="big")
    raw = (tmp_path / "be.raw").read_bytes()
    assert raw == arr.astype(">i2").tobytes()
    assert "endian: big" in path.read_text()
    vol, spacing = load_volume(path)
    _check(vol, arr)
    assert spacing == (2.0, 1.0, 0.5)


def test_nrrd_cross_check_with_pynrrd(tmp_path: Path) -> None:
    nrrd = pytest.importorskip("nrrd")
    arr = _volume("int16", (3, 4, 5))
    header = {
        "space directions": np.diag([0.5, 1.5, 2.0]),
        "space": "left-posterior-superior",
        "encoding": "gzip",
        "endian": "big",
    }
    # pynrrd writes what we read ...
    for detached in (False, True):
        name = "p.nhdr" if detached else "p.nrrd"
        nrrd.write(str(tmp_path / name), arr, dict(header), detached_header=detached, index_order="C")
        vol, spacing = load_volume(tmp_path / name)
        _check(vol, arr[:, ::-1, ::-1])  # LPS: x and y reversed into RAS+
        assert spacing == (0.5, 1.5, 2.0)
    # ... and reads what we write.
    for encoding in ("raw", "gzip"):
        path = save_volume(tmp_path / f"o_{encoding}.nhdr", arr, (0.5, 1.5, 2.0), encoding=encoding, byte_order="big")
        data, hdr = nrrd.read(str(path), index_order="C")
        np.testing.assert_array_equal(data, arr)
        np.testing.assert_allclose(np.linalg.norm(hdr["space directions"], axis=1), [0.5, 1.5, 2.0])


def test_nrrd_header_variants(tmp_path: Path) -> None:
    arr = np.arange(24, dtype="<u2").reshape(2, 3, 4)
    # 'spacings' (nan = unknown -> 1), comments, key/value pairs, type aliases,
    # mixed-case field names, CRLF line ends, line skip and byte skip.
    (tmp_path / "d.bin").write_bytes(b"junk line\n" + b"XYZ" + arr.tobytes())
    text = (
        "NRRD0005\r\n# a comment\r\nType: unsigned short\r\ndimension: 3\r\nsizes: 4 3 2\r\n"
        "spacings: 2 nan 0.5\r\nendian: little\r\nencoding: raw\r\nmodality:=CT\r\n"
        "line skip: 1\r\nbyte skip: 3\r\ndata file: d.bin\r\n"
    )
    (tmp_path / "h.nhdr").write_text(text, newline="")
    vol, spacing = load_volume(tmp_path / "h.nhdr")
    _check(vol, arr)
    assert spacing == (2.0, 1.0, 0.5)


def test_nrrd_byte_skip_minus_one_and_absolute_data_file(tmp_path: Path) -> None:
    arr = np.arange(24, dtype="<f4").reshape(2, 3, 4)
    data = tmp_path / "sub" / "d.dat"
    data.parent.mkdir()
    data.write_bytes(b"some foreign header" + arr.tobytes())
    (tmp_path / "h.nhdr").write_text(_nrrd_header(type="float", endian="little", byte_skip="-1", data_file=str(data)))
    vol, _ = load_volume(tmp_path / "h.nhdr")
    _check(vol, arr)


def test_oblique_space_directions_use_vector_lengths(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    arr = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)
    (tmp_path / "my data.raw").write_bytes(arr.tobytes())  # a data file name with a space
    (tmp_path / "o.nhdr").write_text(
        _nrrd_header(space_dimension="3", space_directions="(0.6,0.8,0) (-1.6,1.2,0) (0,0,-3)", data_file="my data.raw")
    )
    with caplog.at_level("INFO", logger="hevr.volume.nrrd_space"):
        vol, spacing = load_volume(tmp_path / "o.nhdr")
    _check(vol, arr)
    assert spacing == pytest.approx((1.0, 2.0, 3.0))
    assert "o.nhdr" in caplog.text and "non-axis-aligned" in caplog.text


def test_attached_gzip_with_byte_skip(tmp_path: Path) -> None:
    arr = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)
    body = gzip.compress(b"\0" * 5 + arr.tobytes())
    (tmp_path / "a.nrrd").write_bytes((_nrrd_header(encoding="gzip", byte_skip="5") + "\n").encode() + body)
    vol, _ = load_volume(tmp_path / "a.nrrd")
    _check(vol, arr)


# ----------------------------------------------------------------------------- NIfTI


def test_nifti_round_trip(tmp_path: Path) -> None:
    nib = pytest.importorskip("nibabel")
    arr = _volume("int16", (3, 4, 5))  # (z, y, x)
    img = nib.Nifti1Image(arr.transpose(2, 1, 0), np.diag([0.5, 0.75, 2.0, 1.0]))
    for name in ("v.nii", "v.nii.gz"):
        nib.save(img, str(tmp_path / name))
        vol, spacing = load_volume(tmp_path / name)
        _check(vol, arr)
        assert spacing == pytest.approx((0.5, 0.75, 2.0))


@pytest.mark.parametrize(
    "slope, inter, dtype", [(2.0, -10.0, np.int16), (1.0, -40000.0, np.int32), (0.5, 0.0, np.float32)]
)
def test_nifti_scaling(tmp_path: Path, slope: float, inter: float, dtype: type) -> None:
    nib = pytest.importorskip("nibabel")
    arr = np.arange(60, dtype=np.int16).reshape(3, 4, 5)
    img = nib.Nifti1Image(arr.transpose(2, 1, 0), np.eye(4))
    img.header.set_slope_inter(slope, inter)
    nib.save(img, str(tmp_path / "s.nii"))
    vol, _ = load_volume(tmp_path / "s.nii")
    assert vol.dtype == dtype
    np.testing.assert_array_equal(vol, arr * slope + inter)


def test_nifti_trailing_singleton_and_4d(tmp_path: Path) -> None:
    nib = pytest.importorskip("nibabel")
    arr = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    nib.save(nib.Nifti1Image(arr.transpose(2, 1, 0)[..., None], np.eye(4)), str(tmp_path / "one.nii"))
    vol, _ = load_volume(tmp_path / "one.nii")
    _check(vol, arr)
    nib.save(nib.Nifti1Image(np.zeros((4, 3, 2, 2), np.float32), np.eye(4)), str(tmp_path / "four.nii"))
    with pytest.raises(VolumeFormatError, match=r"four\.nii: holds 2 volumes.*volume=i \(CLI --volume i\)"):
        load_volume(tmp_path / "four.nii")
    vol, _ = load_volume(tmp_path / "four.nii", volume=1)
    assert vol.shape == (2, 3, 4)


# ----------------------------------------------------------------------------- missing extras


@pytest.mark.parametrize(
    "module, make",
    [("nibabel", "brain.nii.gz"), ("nibabel", "brain.mgz"), ("pydicom", "folder"), ("tifffile", "cells.tif")],
)
def test_missing_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, module: str, make: str) -> None:
    monkeypatch.setitem(sys.modules, module, None)  # makes "import module" fail
    if make != "folder":
        target = tmp_path / make
        target.write_bytes(b"")
    else:
        target = tmp_path / "series"
        target.mkdir()
    with pytest.raises(MissingDependencyError, match=r"pip install 'hevr\[io\]'") as info:
        load_volume(target)
    assert target.name in str(info.value) and module in str(info.value)
    assert isinstance(info.value, ImportError)


# ----------------------------------------------------------------------------- bad input


def _bad(tmp_path: Path, case: str) -> Path:
    """Create the broken file for ``case``; return the path to load."""
    u8 = np.zeros((2, 3, 4), np.uint8).tobytes()
    files: dict[str, tuple[str, bytes | str]] = {
        "unknown-extension": ("vol.xyz", u8),
        "no-extension": ("volume", u8),
        "raw-no-shape": ("scan.raw", u8),
        "raw-no-dtype": ("scan_4x3x2.raw", u8),
        "raw-truncated": ("scan_4x3x2_uint16.raw", u8),
        "raw-too-long": ("scan_4x3x2_uint8.raw", u8 + b"\0"),
        "nrrd-magic": ("m.nrrd", "NRRD_XX\n" + "type: uint8\n\n"),
        "nrrd-2d": ("d.nrrd", _nrrd_header(dimension="2", sizes="4 3") + "\n"),
        "nrrd-5d": ("d.nhdr", _nrrd_header(dimension="5", sizes="4 3 2 1 1", data_file="d.raw")),
        "nrrd-4d-two": ("d.nhdr", _nrrd_header(dimension="4", sizes="4 3 1 2", data_file="d.raw")),
        "nrrd-sizes": ("s.nhdr", _nrrd_header(sizes="4 3", data_file="d.raw")),
        "nrrd-missing-field": ("f.nhdr", _nrrd_header(encoding=None, data_file="d.raw")),
        "nrrd-type": ("t.nhdr", _nrrd_header(type="block", data_file="d.raw")),
        "nrrd-encoding": ("e.nhdr", _nrrd_header(encoding="zrl", data_file="d.raw")),
        "nrrd-ascii": ("e.nhdr", _nrrd_header(encoding="ascii", data_file="d.raw")),
        "nrrd-bzip2": ("e.nhdr", _nrrd_header(encoding="bzip2", data_file="d.raw")),
        "nrrd-hex": ("e.nhdr", _nrrd_header(encoding="hex", data_file="d.raw")),
        "nrrd-space": ("sp.nhdr", _nrrd_header(space="left-handed-nonsense", data_file="d.raw")),
        "nrrd-endian": ("n.nhdr", _nrrd_header(type="int16", data_file="d.raw")),
        "nrrd-list": ("l.nhdr", _nrrd_header(data_file="LIST") + "d.raw\n"),
        "nrrd-multi": ("l.nhdr", _nrrd_header(data_file="slice%03d.raw 1 2 1")),
        "nrrd-truncated": ("tr.nhdr", _nrrd_header(sizes="4 3 3", data_file="d.raw")),
        "nrrd-wrong-sizes": ("w.nhdr", _nrrd_header(sizes="4 3 1", data_file="d.raw")),
        "nrrd-attached-truncated": ("a.nrrd", _nrrd_header() + "\n" + "x" * 10),
        "nrrd-kinds": ("k.nhdr", _nrrd_header(kinds="RGB-color domain domain", data_file="d.raw")),
        "nrrd-directions": ("sd.nhdr", _nrrd_header(space_directions="(1,0,0) none (0,0,1)", data_file="d.raw")),
        "nrrd-zero-spacing": ("zs.nhdr", _nrrd_header(spacings="1 0 1", data_file="d.raw")),
        "nrrd-gzip-corrupt": ("g.nhdr", _nrrd_header(encoding="gzip", data_file="d.raw")),
        "nrrd-gzip-short": ("gs.nhdr", _nrrd_header(encoding="gzip", data_file="short.raw.gz")),
        "npy-2d": ("two.npy", "npy:2d"),
        "npy-bool": ("mask.npy", "npy:bool"),
        "npy-complex": ("c.npy", "npy:complex"),
        "npy-object": ("o.npy", "npy:object"),
        "npy-empty": ("e.npy", "npy:empty"),
        "npy-truncated": ("t.npy", "npy:truncated"),
        "npy-garbage": ("g.npy", b"this is not numpy"),
        "nifti-garbage": ("g.nii", b"\0" * 10),
    }
    name, content = files[case]
    (tmp_path / "d.raw").write_bytes(u8)
    (tmp_path / "short.raw.gz").write_bytes(gzip.compress(u8[:-1]))
    path = tmp_path / name
    if isinstance(content, str) and content.startswith("npy:"):
        kind = content[4:]
        if kind == "2d":
            np.save(path, np.zeros((3, 4)))
        elif kind == "bool":
            np.save(path, np.zeros((2, 2, 2), bool))
        elif kind == "complex":
            np.save(path, np.zeros((2, 2, 2), np.complex64))
        elif kind == "object":
            np.save(path, np.empty((2, 2, 2), object), allow_pickle=True)
        elif kind == "empty":
            np.save(path, np.zeros((0, 2, 2), np.uint8))
        else:
            np.save(path, np.zeros((4, 4, 4), np.uint16))
            path.write_bytes(path.read_bytes()[:-10])
    else:
        path.write_bytes(content.encode() if isinstance(content, str) else content)
    return path


BAD_CASES = {
    "unknown-extension": "unknown volume file extension '.xyz'",
    "no-extension": "unknown volume file extension",
    "raw-no-shape": "cannot tell the shape and dtype",
    "raw-no-dtype": "cannot tell the dtype",
    "raw-truncated": "truncated: expected 48 bytes",
    "raw-too-long": "size mismatch: expected 24 bytes",
    "nrrd-magic": "not an NRRD file",
    "nrrd-2d": "expected a 3-D volume",
    "nrrd-5d": "expected a 3-D volume",
    "nrrd-4d-two": "holds 2 volumes along its axis 3",
    "nrrd-sizes": "'sizes' must hold 3",
    "nrrd-missing-field": "lacks the required field 'encoding'",
    "nrrd-type": "type 'block' is not supported",
    "nrrd-encoding": "encoding 'zrl' is not supported",
    "nrrd-ascii": "ascii data in d.raw",
    "nrrd-bzip2": "corrupt or truncated bzip2 data",
    "nrrd-hex": "hex data: expected hexadecimal digits",
    "nrrd-space": "NRRD field 'space': expected one of",
    "nrrd-endian": "'endian' must be 'little' or 'big'",
    "nrrd-list": "several files",
    "nrrd-multi": "several files",
    "nrrd-truncated": "truncated",
    "nrrd-wrong-sizes": "size mismatch",
    "nrrd-attached-truncated": "truncated",
    "nrrd-kinds": "expected a scalar 3-D volume",
    "nrrd-directions": "space directions",
    "nrrd-zero-spacing": "positive finite",
    "nrrd-gzip-corrupt": "gzip",
    "nrrd-gzip-short": "truncated",
    "npy-2d": "expected a 3-D volume, got a 2-D",
    "npy-bool": "integer or floating-point",
    "npy-complex": "integer or floating-point",
    "npy-object": "not a valid .npy",
    "npy-empty": "empty",
    "npy-truncated": "not a valid .npy",
    "npy-garbage": "not a valid .npy",
    "nifti-garbage": "cannot read NIfTI",
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input(tmp_path: Path, case: str) -> None:
    if case.startswith("nifti"):
        pytest.importorskip("nibabel")
    path = _bad(tmp_path, case)
    with pytest.raises(VolumeFormatError) as info:
        load_volume(path)
    message = str(info.value)
    # The message names the file (the header or the data file it points to) and the problem.
    assert path.name in message or "d.raw" in message or "short.raw.gz" in message, message
    assert BAD_CASES[case] in message, message
    assert isinstance(info.value, (HevrError, ValueError))


@pytest.mark.parametrize("name", ["nope.npy", "nope.nhdr", "nope_dir"])
def test_missing_file(tmp_path: Path, name: str) -> None:
    with pytest.raises(FileNotFoundError, match="nope"):
        load_volume(tmp_path / name)


def test_missing_nrrd_data_file(tmp_path: Path) -> None:
    (tmp_path / "h.nhdr").write_text(_nrrd_header(data_file="gone.raw"))
    with pytest.raises(FileNotFoundError, match=r"gone\.raw"):
        load_volume(tmp_path / "h.nhdr")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"byte_order": "middle"}, "byte_order"),
        ({"spacing": (1, 0, 1)}, "spacing"),
        ({"spacing": (1, 1)}, "spacing"),
        ({"spacing": "abc"}, "spacing"),
        ({"spacing": "123"}, "spacing"),
        ({"spacing": (1, float("nan"), 1)}, "spacing"),
        ({"shape": (2, 3)}, "shape"),
        ({"shape": (2, 3, -4)}, "shape"),
        ({"shape": (2, 3, 4), "dtype": "complex64"}, "dtype"),
        ({"shape": (2, 3, 4), "dtype": "no-such-type"}, "dtype"),
    ],
)
def test_bad_load_parameters(tmp_path: Path, kwargs: dict, match: str) -> None:
    path = tmp_path / "v_4x3x2_uint8.raw"
    path.write_bytes(bytes(24))
    with pytest.raises(ParameterError, match=match):
        load_volume(path, **kwargs)


def test_shape_and_dtype_only_for_raw(tmp_path: Path) -> None:
    path = save_volume(tmp_path / "v.npy", np.zeros((2, 2, 2), np.uint8))
    with pytest.raises(ParameterError, match=r"only apply to \.raw.*v\.npy"):
        load_volume(path, shape=(2, 2, 2))


@pytest.mark.parametrize(
    "name, vol, kwargs, match",
    [
        ("v.npy", np.zeros((2, 2)), {}, "3-D"),
        ("v.npy", np.zeros((2, 2, 2), bool), {}, "integer or float"),
        ("v.npy", np.zeros((2, 2, 2)), {"spacing": (1, -1, 1)}, "spacing"),
        ("v.tif", np.zeros((2, 2, 2)), {}, r"\.npy, \.raw, \.nhdr or \.nrrd, got v\.tif"),
        ("v.npy", np.zeros((2, 2, 2)), {"encoding": "gzip"}, "needs an NRRD"),
        ("v.nhdr", np.zeros((2, 2, 2)), {"encoding": "bz2"}, "encoding"),
        ("v.nhdr", np.zeros((2, 2, 2)), {"byte_order": "native"}, "byte_order"),
        ("v.nhdr", np.zeros((2, 2, 2), np.float16), {}, "float16"),
        ("v_2x2x3_uint8.raw", np.zeros((2, 2, 2), np.uint8), {}, r"v_2x2x3_uint8\.raw"),
        ("v_2x2x2_int16.raw", np.zeros((2, 2, 2), np.uint8), {}, "int16"),
    ],
)
def test_bad_save_parameters(tmp_path: Path, name: str, vol: np.ndarray, kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        save_volume(tmp_path / name, vol, **kwargs)


def test_format_dispatch(tmp_path: Path) -> None:
    for name, kind in [
        ("a.npy", "npy"),
        ("a_2x2x2_uint8.raw", "raw"),
        ("a.NHDR", "nrrd"),
        ("a.nrrd", "nrrd"),
        ("a.nii", "nifti"),
        ("a.nii.gz", "nifti"),
        ("a.mgz", "nifti"),
        ("a.mgh", "nifti"),
        ("a.tif", "tiff"),
        ("a.ome.tiff", "tiff"),
        ("a.dcm", "dicom"),
        ("a.IMA", "dicom"),
        ("DICOMDIR", "dicom"),
    ]:
        (tmp_path / name).write_bytes(b"")
        assert _format(tmp_path / name) == kind, name
    for folder, marker, kind in [
        ("v3.zarr", "zarr.json", "zarr"),
        ("v2", ".zarray", "zarr"),
        ("g2", ".zgroup", "zarr"),
        ("series", "IM0001", "dicom"),
    ]:
        (tmp_path / folder).mkdir()
        (tmp_path / folder / marker).write_text("{}")
        assert _format(tmp_path / folder) == kind, folder
    (tmp_path / "a.xyz").write_bytes(b"")
    with pytest.raises(VolumeFormatError, match=r"a\.xyz: unknown .*expected .*\.mgz.*\.tiff.*DICOMDIR.*Zarr"):
        _format(tmp_path / "a.xyz")
