"""NRRD: every data encoding (files written by pynrrd, hex by hand) and 4-D files (vector
components, time points) through hevr.read_scan."""

from __future__ import annotations

import bz2
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.errors import MissingDependencyError, ParameterError, VolumeFormatError

nrrd = pytest.importorskip("nrrd")

ARR = np.arange(3 * 4 * 5, dtype=np.int16).reshape(3, 4, 5) * 37 - 900  # (z, y, x)
SPACE = {
    "space": "right-anterior-superior",
    "space directions": np.diag([0.5, 1.5, 2.0]),
    "space origin": np.array([1.0, 2.0, 3.0]),
}


@pytest.mark.parametrize("detached", [False, True], ids=["attached", "detached"])
@pytest.mark.parametrize("encoding", ["raw", "gzip", "bzip2", "ascii", "gz", "bz2", "text", "txt"])
def test_every_pynrrd_encoding_reads_the_same(tmp_path: Path, encoding: str, detached: bool) -> None:
    path = tmp_path / ("v.nhdr" if detached else "v.nrrd")
    nrrd.write(
        str(path), ARR, {**SPACE, "encoding": encoding, "endian": "big"}, index_order="C", detached_header=detached
    )
    scan = hevr.read_scan(path)
    assert scan.volume.dtype == np.int16 and scan.volume.dtype.isnative
    np.testing.assert_array_equal(scan.volume, ARR)
    assert scan.spacing == (0.5, 1.5, 2.0) and scan.origin == (1.0, 2.0, 3.0) and scan.frame == "RAS"
    assert scan.details["encoding"] == encoding
    if encoding == "raw":
        assert isinstance(scan.volume, np.memmap)


@pytest.mark.parametrize("dtype", ["uint8", "int16", "float32", "float64"])
def test_hex_encoding(tmp_path: Path, dtype: str) -> None:
    arr = ARR.astype(dtype)
    text = arr.astype(np.dtype(dtype).newbyteorder(">")).tobytes().hex()
    body = "\n".join(text[i : i + 30].upper() if i % 60 else text[i : i + 30] for i in range(0, len(text), 30))
    header = (
        f"NRRD0004\ntype: {({'float32': 'float', 'float64': 'double'}).get(dtype, dtype)}\ndimension: 3\nsizes: 5 4 3\n"
        "endian: big\nencoding: hex\n\n"
    )
    (tmp_path / "h.nrrd").write_text(header + body + "\n")
    np.testing.assert_array_equal(hevr.load_volume(tmp_path / "h.nrrd")[0], arr)
    (tmp_path / "odd.nrrd").write_text(header + text[:-1])
    with pytest.raises(VolumeFormatError, match=r"odd\.nrrd: hex data"):
        hevr.load_volume(tmp_path / "odd.nrrd")


def test_bzip2_bomb_is_not_decompressed(tmp_path: Path) -> None:
    path = tmp_path / "bomb.nrrd"
    header = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: bzip2\n\n"
    path.write_bytes(header.encode() + bz2.compress(bytes(16 << 20)))  # 16 MiB of zeros in ~100 bytes
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(VolumeFormatError, match=r"bomb\.nrrd: size mismatch: .*expected 8 bytes"):
            hevr.load_volume(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - t0 < 1.0 and peak < 4 << 20


def test_ascii_needs_pynrrd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    nrrd.write(str(tmp_path / "a.nrrd"), ARR, {"encoding": "ascii"}, index_order="C")
    monkeypatch.setitem(sys.modules, "nrrd", None)
    with pytest.raises(MissingDependencyError, match=r"a\.nrrd.*'nrrd'.*hevr\[io\]"):
        hevr.load_volume(tmp_path / "a.nrrd")


def test_ascii_with_too_few_numbers(tmp_path: Path) -> None:
    (tmp_path / "few.nrrd").write_text("NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nencoding: ascii\n\n1 2 3\n")
    with pytest.raises(VolumeFormatError, match=r"few\.nrrd: ascii data in few\.nrrd: .*8 numbers"):
        hevr.load_volume(tmp_path / "few.nrrd")


# -- 4-D files ------------------------------------------------------------------------------------

VEC = np.arange(3 * 4 * 5 * 3, dtype=np.float32).reshape(3, 4, 5, 3)  # (z, y, x, component)


def _vector_file(tmp_path: Path, encoding: str = "raw") -> Path:
    header = {
        "kinds": ["vector", "domain", "domain", "domain"],
        "space": "left-posterior-superior",
        "space directions": np.array([[np.nan] * 3, [1.0, 0, 0], [0, 2.0, 0], [0, 0, 3.0]]),
        "encoding": encoding,
    }
    nrrd.write(str(tmp_path / f"vec_{encoding}.nrrd"), VEC, header, index_order="C")
    return tmp_path / f"vec_{encoding}.nrrd"


@pytest.mark.parametrize("encoding", ["raw", "gzip"])
def test_vector_nrrd_refused_or_component_picked(tmp_path: Path, encoding: str) -> None:
    path = _vector_file(tmp_path, encoding)
    assert "none" in path.read_bytes()[:400].decode("latin-1")  # pynrrd wrote the non-spatial axis as 'none'
    with pytest.raises(VolumeFormatError) as info:
        hevr.load_volume(path)
    msg = str(info.value)
    assert msg.startswith(f"{path.name}: holds 3 vector components") and "one scalar per voxel" in msg
    assert "volume=" in msg
    for c in range(3):
        scan = hevr.read_scan(path, volume=c)
        # LPS: x and y reversed into RAS+.
        np.testing.assert_array_equal(scan.volume, VEC[:, ::-1, ::-1, c])
        assert scan.spacing == (1.0, 2.0, 3.0) and scan.frame == "RAS"
    with pytest.raises(ParameterError, match=r"^volume: expected an index in \[0, 2\]"):
        hevr.read_scan(path, volume=3)


def test_time_nrrd_picks_a_volume(tmp_path: Path) -> None:
    series = np.arange(2 * 3 * 4 * 5, dtype=np.uint16).reshape(2, 3, 4, 5)  # (t, z, y, x)
    header = {"kinds": ["domain", "domain", "domain", "time"], "encoding": "raw", "spacings": [0.5, 1, 2, np.nan]}
    nrrd.write(str(tmp_path / "t.nrrd"), series, header, index_order="C")
    with pytest.raises(VolumeFormatError, match=r"t\.nrrd: holds 2 volumes along its axis 3 \(kind time\)"):
        hevr.load_volume(tmp_path / "t.nrrd")
    vol, spacing = hevr.load_volume(tmp_path / "t.nrrd", volume=1)
    np.testing.assert_array_equal(vol, series[1])
    assert spacing == (0.5, 1.0, 2.0) and isinstance(vol, np.memmap)


def test_singleton_4th_axis_and_volume_for_3d(tmp_path: Path) -> None:
    nrrd.write(str(tmp_path / "one.nrrd"), ARR[None], {"encoding": "raw"}, index_order="C")
    np.testing.assert_array_equal(hevr.load_volume(tmp_path / "one.nrrd")[0], ARR)  # a 4th axis of 1: no choice
    nrrd.write(str(tmp_path / "plain.nrrd"), ARR, {"encoding": "raw"}, index_order="C")
    with pytest.raises(ParameterError, match=r"plain\.nrrd holds a single 3-D volume"):
        hevr.load_volume(tmp_path / "plain.nrrd", volume=0)


@pytest.mark.parametrize(
    "fields, match",
    [
        ({"kinds": "domain domain domain domain"}, "exactly one non-spatial axis"),
        ({"kinds": "vector vector domain domain"}, "exactly one non-spatial axis"),
        ({"space directions": "(1,0,0) (0,1,0) (0,0,1) (1,1,1)"}, "space directions"),
        ({"space directions": "none none (0,1,0) (0,0,1)"}, "space directions"),
        ({"kinds": "domain domain domain"}, "'kinds' must name 4 axes"),
        ({"space origin": "(1,2)"}, "space origin"),
    ],
)
def test_bad_4d_headers(tmp_path: Path, fields: dict, match: str) -> None:
    lines = ["NRRD0004", "type: uint8", "dimension: 4", "sizes: 2 2 2 2", "encoding: raw"]
    lines += [f"{k}: {v}" for k, v in fields.items()]
    (tmp_path / "b.nrrd").write_bytes(("\n".join(lines) + "\n\n").encode() + bytes(16))
    with pytest.raises(VolumeFormatError, match=match) as info:
        hevr.load_volume(tmp_path / "b.nrrd", volume=0)
    assert str(info.value).startswith("b.nrrd: ")


def test_4d_refused_before_the_data_is_read(tmp_path: Path) -> None:
    header = (
        "NRRD0004\ntype: uint8\ndimension: 4\nsizes: 3 2 2 2\nkinds: RGB-color domain domain domain\nencoding: gzip\n\n"
    )
    (tmp_path / "c.nrrd").write_bytes(header.encode() + b"not gzip at all")
    with pytest.raises(VolumeFormatError, match=r"c\.nrrd: holds 3 rgb-color components"):
        hevr.load_volume(tmp_path / "c.nrrd")  # the header decides; the broken data is never touched
    with pytest.raises(VolumeFormatError, match=r"c\.nrrd: corrupt or truncated gzip data"):
        hevr.load_volume(tmp_path / "c.nrrd", volume=0)
