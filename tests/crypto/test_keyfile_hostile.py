"""hevr.load_key on hostile files: every one ends in InvalidKeyError naming the field or the
problem, fast, without quoting a secret, and without reading more than a key file's size."""

from __future__ import annotations

import json
import os
import time
import tracemalloc
import warnings

import pytest

import hevr
from hevr.crypto.keyfile import MAX_KEY_FILE_BYTES, load_key

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _secrets(priv) -> list[str]:
    p, q = int(priv.p), int(priv.q)
    return [str(p), str(q), hex(p)[2:], hex(q)[2:]]


def _load(path) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        with pytest.raises(hevr.InvalidKeyError) as info:
            load_key(path)
    return str(info.value)


def _ascii_to(digits: str, text: str) -> str:
    """``text`` with its ASCII digits replaced by the ten characters of ``digits``."""
    return text.translate(str.maketrans("0123456789", digits))


ARABIC_INDIC = "٠١٢٣٤٥٦٧٨٩"
FULLWIDTH = "０１２３４５６７８９"
DEVANAGARI = "०१२३४५६७८९"


@pytest.mark.parametrize("field", ["n", "p", "q"])
@pytest.mark.parametrize("digits", [ARABIC_INDIC, FULLWIDTH, DEVANAGARI], ids=["arabic", "fullwidth", "devanagari"])
def test_non_ascii_digits_are_refused(tmp_path, keypair256, field, digits):
    _, priv = keypair256
    d = priv.to_dict()
    assert int(_ascii_to(digits, d[field])) == int(d[field])  # what Python's int() would accept
    d[field] = _ascii_to(digits, d[field])
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d, ensure_ascii=False), encoding="utf-8")
    msg = _load(path)
    assert f"field {field!r}: expected a decimal string" in msg and "ASCII digits" in msg
    assert not any(s in msg for s in _secrets(priv))


@pytest.mark.parametrize(
    "value, got",
    [
        ("1_000", "other than 0-9"),
        (" 12", "other than 0-9"),
        ("-7", "other than 0-9"),
        ("+7", "other than 0-9"),
        ("", "other than 0-9"),
        ("²", "other than 0-9"),
        (12, "a JSON int"),
        (None, "nothing"),
        ("9" * 5000, "5000 digits"),
    ],
)
def test_bad_decimal_fields_name_the_field(tmp_path, keypair256, value, got):
    _, priv = keypair256
    d = priv.to_dict()
    d["p"] = value
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d))
    msg = _load(path)
    assert "field 'p': expected" in msg and got in msg


@pytest.mark.parametrize(
    "raw, needle",
    [
        (b'{"format": "hevr-key", "n": "\xff\xfe"}', "not UTF-8"),
        (b"\xe9t\xe9", "not UTF-8"),
        (b"[" * 60000, "nested too deeply"),
        (b'{"format": "hevr-key", "version": ' + b"1" * 5000 + b"}", "number too long"),
        (b" " * (MAX_KEY_FILE_BYTES + 1), f"expected at most {MAX_KEY_FILE_BYTES} bytes"),
    ],
)
def test_hostile_bytes(tmp_path, raw, needle):
    path = tmp_path / "k.json"
    path.write_bytes(raw)
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        msg = _load(path)
        seconds, peak = time.perf_counter() - t0, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert needle in msg
    assert seconds < 1.0 and peak < 4 << 20


def test_huge_file_is_not_read(tmp_path):
    path = tmp_path / "k.json"
    with open(path, "wb") as fh:  # sparse: 1 GiB on paper, nothing on disk
        fh.truncate(1 << 30)
    tracemalloc.start()
    try:
        msg = _load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "expected at most" in msg and peak < 1 << 20


def test_folder_and_fifo_are_refused_without_blocking(tmp_path):
    assert "expected a regular file" in _load(tmp_path)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert "expected a regular file" in _load(fifo)  # reading would block forever


@pytest.mark.parametrize(
    "mutate, needle",
    [
        ({"version": True}, "version"),
        ({"version": 1.0}, "version"),
        ({"bits": True}, "bits"),
        ({"bits": "256"}, "bits"),
    ],
)
def test_json_types_are_exact(tmp_path, keypair256, mutate, needle):
    _, priv = keypair256
    d = priv.to_dict()
    d.update(mutate)
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d))
    assert needle in _load(path)


def test_valid_files_still_load(tmp_path, keypair256):
    pub, priv = keypair256
    priv.save(tmp_path / "k.json")
    pub.save(tmp_path / "k.pub.json")
    assert load_key(tmp_path / "k.json") == priv and load_key(tmp_path / "k.pub.json") == pub
