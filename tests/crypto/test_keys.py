"""Key generation, key files (0600, round trip, tampering), no secrets in reprs, phe interop."""

from __future__ import annotations

import json
import os
import stat
import warnings

import gmpy2
import phe
import pytest

import hevr
from hevr.crypto.keyfile import load_key
from hevr.crypto.keys import PrivateKey, PublicKey, generate_keypair


@pytest.mark.parametrize("bits", [64, 66, 128, 256, 510, 512])
def test_generate_sizes(bits):
    with pytest.warns(hevr.InsecureKeyWarning):
        pub, priv = generate_keypair(bits)
    assert pub.bits == bits == pub.n.bit_length()
    assert priv.p != priv.q and priv.p * priv.q == pub.n
    assert priv.p.bit_length() == priv.q.bit_length() == bits // 2
    assert gmpy2.gcd(pub.n, (priv.p - 1) * (priv.q - 1)) == 1
    assert pub.g == pub.n + 1


def test_2048_no_warning(keypair2048):
    pub, priv = keypair2048
    assert pub.bits == 2048
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        PublicKey(pub.n)  # constructing a key object never warns


@pytest.mark.parametrize("bits", [0, 63, 65, 4098, 2047, "2048", 2048.0, True])
def test_generate_bad_bits(bits):
    with pytest.raises(hevr.ParameterError, match="bits"):
        generate_keypair(bits)


def test_fingerprint_is_sha256_of_n(keypair256):
    import hashlib

    pub, _ = keypair256
    nb = int(pub.n).to_bytes((pub.bits + 7) // 8, "big")
    assert pub.fingerprint == hashlib.sha256(nb).hexdigest()


def _secret_strings(priv):
    p, q = int(priv.p), int(priv.q)
    lam = (p - 1) * (q - 1)
    return [str(p), str(q), hex(p)[2:], hex(q)[2:], str(lam), hex(lam)[2:]]


def test_no_secret_in_repr_or_errors(keypair256):
    pub, priv = keypair256
    texts = [repr(priv), str(priv), repr(pub), repr(priv.encrypt_number(1))]
    try:
        PrivateKey(pub, priv.p + 2, priv.q)
    except hevr.ParameterError as exc:
        texts.append(str(exc))
    for t in texts:
        for s in _secret_strings(priv):
            assert s not in t


def test_key_files_round_trip_and_mode(tmp_path, keypair256):
    pub, priv = keypair256
    priv.save(tmp_path / "key.json")
    pub.save(tmp_path / "key.pub.json")
    mode = stat.S_IMODE(os.stat(tmp_path / "key.json").st_mode)
    assert mode == 0o600
    with pytest.warns(hevr.InsecureKeyWarning):
        k = load_key(tmp_path / "key.json")
    assert isinstance(k, PrivateKey) and k == priv
    assert k.decrypt(pub.encrypt(-77)) == -77
    with pytest.warns(hevr.InsecureKeyWarning):
        kp = load_key(tmp_path / "key.pub.json")
    assert isinstance(kp, PublicKey) and kp == pub
    pubtext = (tmp_path / "key.pub.json").read_text()
    for s in _secret_strings(priv):
        assert s not in pubtext


def test_overwriting_private_key_keeps_0600(tmp_path, keypair256):
    path = tmp_path / "key.json"
    path.write_text("old")
    os.chmod(path, 0o644)
    keypair256[1].save(path, overwrite=True)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600


@pytest.mark.parametrize("which", [0, 1], ids=["public", "private"])
def test_saving_over_an_existing_key_is_refused(tmp_path, keypair256, keypair512, which):
    """A Dask worker re-running a script's priv.save used to replace the key silently."""
    path = tmp_path / "key.json"
    keypair256[1].save(path)
    before = path.read_bytes()
    other = keypair512[1]
    key = other if which else other.public_key
    with pytest.raises(hevr.ExistingFileError, match="expected no file at .*key.json .*overwrite=True") as err:
        key.save(path)
    assert isinstance(err.value, FileExistsError) and isinstance(err.value, hevr.HevrError)
    assert path.read_bytes() == before and hevr.load_key(path).public_key.n == keypair256[0].n
    assert sorted(p.name for p in tmp_path.iterdir()) == ["key.json"]  # no temporary file left behind
    key.save(path, overwrite=True)
    again = hevr.load_key(path)
    assert (again.public_key if which else again).n == other.public_key.n


def _tamper(d, **kw):
    d = dict(d)
    d.update(kw)
    return d


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d, pr: _tamper(d, n=str(int(d["n"]) + 2)), "fingerprint|p·q"),
        (lambda d, pr: _tamper(d, fingerprint="0" * 64), "fingerprint"),
        (lambda d, pr: _tamper(d, p=str(int(pr.p) + 2)), "p·q"),
        (lambda d, pr: _tamper(d, p="abc"), "decimal"),
        (lambda d, pr: {k: v for k, v in d.items() if k != "q"}, "'q'"),
        (lambda d, pr: _tamper(d, format="other"), "format"),
        (lambda d, pr: _tamper(d, version=9), "version"),
        (lambda d, pr: _tamper(d, kind="weird"), "kind"),
        (lambda d, pr: _tamper(d, bits=1024), "bits"),
        (
            lambda d, pr: _tamper(
                d, n=str(int(pr.p) * int(pr.p)), p=str(int(pr.p)), q=str(int(pr.p)), fingerprint=None
            ),
            "distinct",
        ),
    ],
)
def test_tampered_files_rejected(tmp_path, keypair256, mutate, match):
    pub, priv = keypair256
    d = mutate(priv.to_dict(), priv)
    d = {k: v for k, v in d.items() if v is not None}
    path = tmp_path / "key.json"
    path.write_text(json.dumps(d))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        with pytest.raises(hevr.InvalidKeyError, match=match) as info:
            load_key(path)
    for s in _secret_strings(priv):
        assert s not in str(info.value)


def test_composite_factors_rejected(tmp_path, keypair256):
    # n = (p·r)·(q/r) style tampering is caught by the primality check
    _, priv = keypair256
    a, b = int(priv.p), int(priv.q)
    d = priv.to_dict()
    d.update(p="1", q=str(a * b))
    (tmp_path / "k.json").write_text(json.dumps(d))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(hevr.InvalidKeyError):
            load_key(tmp_path / "k.json")


@pytest.mark.parametrize("content", ["", "{", "[]", "null"])
def test_malformed_files_rejected(tmp_path, content):
    path = tmp_path / "k.json"
    path.write_text(content)
    with pytest.raises(hevr.InvalidKeyError):
        load_key(path)


def test_missing_file(tmp_path):
    with pytest.raises(hevr.MissingFileError, match="key: expected a key file, found nothing at") as info:
        load_key(tmp_path / "nope.json")
    assert isinstance(info.value, FileNotFoundError) and info.value.filename == str(tmp_path / "nope.json")


@pytest.mark.parametrize("bits", [256, 2048])
def test_phe_interoperability_both_ways(bits, keypair256, keypair2048):
    pub, priv = keypair256 if bits == 256 else keypair2048
    ppub = phe.PaillierPublicKey(int(pub.n))
    ppriv = phe.PaillierPrivateKey(ppub, int(priv.p), int(priv.q))
    for m in (0, 5, 12345):
        assert ppriv.raw_decrypt(int(pub.encrypt(m))) == m
        assert ppriv.raw_decrypt(int(priv.encrypt(m))) == m
        assert priv.decrypt(ppub.raw_encrypt(m)) == m
