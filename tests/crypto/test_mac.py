"""hevr.crypto.mac: known answers (a fixed key, a fixed document, fixed digests and tags), the
RFC 4231 vectors of HMAC-SHA256, and the callers' use of the one helper.

The constants below were computed once with the standard library's ``json``, ``hashlib`` and
``hmac`` written out by hand (not through hevr); every MAC hevr has already written to a store,
a frame or a known-stores file depends on them, so a change here is a format change.
"""

from __future__ import annotations

import hashlib
import hmac

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hevr.crypto import mac as m
from hevr.image import stamp
from hevr.image.proof import view_key
from hevr.rendering.geometry.camera import Camera
from hevr.store import authenticity, known_file

KEY = bytes(range(32))
DOC = {"store": "0123456789abcdef", "shape": [12, 10, 8], "value_range": [0.0, 1.5], "name": "é",
       "nested": {"b": None, "a": True}}  # fmt: skip
CANONICAL = (
    b'{"name":"\\u00e9","nested":{"a":true,"b":null},"shape":[12,10,8],'
    b'"store":"0123456789abcdef","value_range":[0.0,1.5]}'
)
DIGEST = "0e00bb065ccc42682fa300f5b77fa987d0536d102bb659bf6d3c4cad27716cae"
DERIVED = {
    b"hevr-metadata-mac-v1": (
        "267beaf4c1cd1a995087943d5f84f1085a6bc821e8f0a571e0d5d264861bfc91",
        "37c723031933a9f6682b422e3eec252be202ab3d1c244751b92bfd7686cc8fcb",
    ),
    b"hevr-frame-stamp-v1": (
        "9bf62ff433082cea12c08ff6a3251740a9949309431d82f6352f16f5b98f25e7",
        "0cc05fe3a450ad99ea9ed5656d0430bd33878af36ec69c2efc10b65af3cc6488",
    ),
    b"hevr-known-stores-v2": (
        "729fc330139b32e2e30b1ac32f0a501a55f6ed76204cab16bca77f4f55f1d58c",
        "59abdbf1b4c62bf4e7e87ff733d664bfba3fa6f76a269f055a942590c88c628c",
    ),
}


def test_canonical_and_digest_known_answers():
    assert m.canonical(DOC) == CANONICAL
    assert m.digest(DOC).hex() == DIGEST
    assert m.digest(dict(reversed(list(DOC.items())))).hex() == DIGEST  # key order is not part of it


@pytest.mark.parametrize("label", sorted(DERIVED))
def test_derived_keys_and_tags_known_answers(label):
    key_hex, tag_hex = DERIVED[label]
    k = m.derive_key(KEY, label)
    assert k.hex() == key_hex
    assert m.mac(k, DOC) == "hmac-sha256:" + tag_hex


def test_the_callers_macs_are_the_helpers():
    """The metadata MAC, the frame stamp and the known-stores MAC are the helper's, under their labels."""
    meta_key = bytes.fromhex(DERIVED[b"hevr-metadata-mac-v1"][0])
    assert (
        authenticity.raw_metadata_mac(KEY, DOC)
        == m.mac(meta_key, DOC)
        == "hmac-sha256:" + DERIVED[b"hevr-metadata-mac-v1"][1]
    )
    msg = m.digest(DOC) + bytes(32)
    stamp_key = bytes.fromhex(DERIVED[b"hevr-frame-stamp-v1"][0])
    assert stamp.raw_stamp(KEY, msg) == m.raw_mac(stamp_key, msg)
    assert stamp.raw_check(KEY, msg, stamp.raw_stamp(KEY, msg))
    assert not stamp.raw_check(KEY, msg + b"x", stamp.raw_stamp(KEY, msg))
    known = known_file.KnownStore("0123456789abcdef", "sha256:00", True, "ab")
    ks_key = bytes.fromhex(DERIVED[b"hevr-known-stores-v2"][0])
    assert known_file.entry_mac(ks_key, "v.zarr", known) == m.mac(ks_key, ["v.zarr", known.fields()])
    assert authenticity.metadata_digest(DOC) == "sha256:" + DIGEST
    assert view_key(DOC) == DIGEST[:16]
    cam = Camera((0, 0, 5), (0, 0, 0))
    assert cam.key() == hashlib.sha256(m.canonical(cam.to_dict())).hexdigest()


def test_rfc4231_hmac_sha256():
    """RFC 4231 test cases 1 and 2: raw_mac is HMAC-SHA256."""
    assert m.raw_mac(b"\x0b" * 20, b"Hi There") == (
        "hmac-sha256:b0344c61d8db38535ca8afceaf0bf12b881dc200c9833da726e9376c2e32cff7"
    )
    assert m.raw_mac(b"Jefe", b"what do ya want for nothing?") == (
        "hmac-sha256:5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
    )


def test_an_unknown_label_is_refused():
    with pytest.raises(ValueError, match="label: expected one of"):
        m.derive_key(KEY, b"hevr-something-else")


@pytest.mark.parametrize("tag", [None, 1, b"hmac-sha256:00", "hmac-sha256:01", "hmac-sha256:0", "é"])
def test_check_tag_refuses_what_is_not_the_tag(tag):
    assert not m.check_tag("hmac-sha256:00", tag)


json_leaf = st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text()
json_docs = st.recursive(json_leaf, lambda c: st.lists(c) | st.dictionaries(st.text(), c), max_leaves=20)


@given(json_docs, st.binary(min_size=1, max_size=64))
def test_mac_is_hmac_of_the_canonical_bytes(doc, key):
    assert m.canonical(doc).isascii()
    assert m.mac(key, doc) == "hmac-sha256:" + hmac.new(key, m.canonical(doc), hashlib.sha256).hexdigest()
    assert m.check_tag(m.mac(key, doc), m.mac(key, doc))
