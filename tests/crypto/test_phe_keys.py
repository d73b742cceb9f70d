"""python-paillier (phe / pheutil) key files: hevr reads them, writes them, and the two
libraries encrypt and decrypt for each other — through phe's own code paths wherever phe has
one (pheutil's commands via click's CliRunner, its loaders, its base64 helpers)."""

from __future__ import annotations

import json
import os
import re
import stat
import warnings

import gmpy2
import numpy as np
import pytest
from click.testing import (
    CliRunner,  # click: a dependency of distributed; pheutil is a click app
)
from phe import command_line, paillier
from phe.util import base64_to_int, int_to_base64

import hevr
from hevr.crypto.keyfile import MAX_KEY_FILE_BYTES
from hevr.crypto.keys import MAX_BITS
from hevr.crypto.phe_keys import factor_from_lambda, key_from_phe_dict, phe_key_dict
from hevr.crypto.primes import is_probable_prime

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

VALUES = [0, 1, -1, 42, -123456789, 2**60 + 7]


def _pheutil(*args: str) -> str:
    """Run a pheutil command in-process; its stdout."""
    result = CliRunner().invoke(command_line.cli, list(args), catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.stdout


def _load(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        return hevr.load_key(path)


@pytest.fixture(scope="module")
def pheutil_keys(tmp_path_factory):
    """A 512-bit key pair made by ``pheutil genpkey`` / ``pheutil extract`` themselves."""
    folder = tmp_path_factory.mktemp("pheutil")
    priv_path, pub_path = folder / "k.json", folder / "k.pub.json"
    _pheutil("genpkey", "--keysize", "512", str(priv_path))
    _pheutil("extract", str(priv_path), str(pub_path))
    return priv_path, pub_path


def _phe_private(path) -> paillier.PaillierPrivateKey:
    """phe's own reading of a pheutil private key file (as ``pheutil decrypt`` does it)."""
    d = json.loads(path.read_text())
    pub = command_line.load_public_key(d["pub"])
    return paillier.PaillierPrivateKey(pub, base64_to_int(d["p"]), base64_to_int(d["q"]))


def _pheutil_decrypt(priv_path, c: int, tmp_path) -> str:
    ct = tmp_path / "c.json"
    ct.write_text(json.dumps({"v": str(int(c)), "e": 0}))
    return _pheutil("decrypt", str(priv_path), str(ct)).strip()


# -- hevr -> phe file -> hevr --------------------------------------------------------------------


@pytest.mark.parametrize("which", ["public", "private"])
def test_round_trip_through_a_phe_file(tmp_path, keypair, which):
    pub, priv = keypair
    key = priv if which == "private" else pub
    path = tmp_path / "k.json"
    key.save(path, format="phe")
    d = json.loads(path.read_text())
    assert d["kty"] == "DAJ" and (d["pub"] if which == "private" else d)["alg"] == "PAI-GN1"
    back = _load(path)
    assert type(back) is type(key) and back == key
    if which == "private":
        assert (back.p, back.q, back.fingerprint) == (priv.p, priv.q, priv.fingerprint)
        assert d["p"] == int_to_base64(int(priv.p)) and d["q"] == int_to_base64(int(priv.q))
    else:
        assert back.n == pub.n and back.fingerprint == pub.fingerprint and d["n"] == int_to_base64(int(pub.n))


def test_dict_functions_round_trip(keypair256):
    pub, priv = keypair256
    assert key_from_phe_dict(phe_key_dict(priv), "mem") == priv
    assert key_from_phe_dict(phe_key_dict(pub), "mem") == pub
    assert phe_key_dict(priv)["pub"] == phe_key_dict(pub) == pub.to_dict("phe")
    with pytest.raises(hevr.ParameterError, match="key: expected a PublicKey or PrivateKey, got int"):
        phe_key_dict(7)


@pytest.mark.parametrize("fmt", ["pem", "PHE", None, 1])
def test_unknown_format_is_refused_before_writing(tmp_path, keypair256, fmt):
    for key in keypair256:
        with pytest.raises(hevr.ParameterError, match=r"format: expected 'hevr' or 'phe', got "):
            key.save(tmp_path / "k.json", format=fmt)
    assert list(tmp_path.iterdir()) == []


def test_file_modes_and_overwrite(tmp_path, keypair256, keypair512):
    pub, priv = keypair256
    priv.save(tmp_path / "k.json", format="phe")
    pub.save(tmp_path / "k.pub.json", format="phe")
    assert stat.S_IMODE(os.stat(tmp_path / "k.json").st_mode) == 0o600
    assert stat.S_IMODE(os.stat(tmp_path / "k.pub.json").st_mode) == 0o644
    before = (tmp_path / "k.json").read_bytes()
    for key in keypair512:
        with pytest.raises(hevr.ExistingFileError, match="overwrite=True"):
            key.save(tmp_path / "k.json", format="phe")
    assert (tmp_path / "k.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.json", "k.pub.json"]
    keypair512[1].save(tmp_path / "k.json", overwrite=True, format="phe")
    assert _load(tmp_path / "k.json") == keypair512[1]
    assert stat.S_IMODE(os.stat(tmp_path / "k.json").st_mode) == 0o600


def test_2048_bit_key_round_trips_and_phe_decrypts(tmp_path, keypair2048):
    pub, priv = keypair2048
    priv.save(tmp_path / "k.json", format="phe")
    with warnings.catch_warnings():
        warnings.simplefilter("error", hevr.InsecureKeyWarning)  # 2048 bits: no warning
        assert hevr.load_key(tmp_path / "k.json") == priv
    assert _phe_private(tmp_path / "k.json").raw_decrypt(int(priv.encrypt(31337))) == 31337


# -- keys made by pheutil ------------------------------------------------------------------------


def test_pheutil_files_load(pheutil_keys):
    priv_path, pub_path = pheutil_keys
    with pytest.warns(hevr.InsecureKeyWarning, match="512-bit"):
        priv = hevr.load_key(priv_path)
    pub = _load(pub_path)
    assert isinstance(priv, hevr.PrivateKey) and isinstance(pub, hevr.PublicKey)
    assert priv.public_key == pub and pub.bits == 512
    phe_priv = _phe_private(priv_path)
    assert (priv.p, priv.q) == (phe_priv.p, phe_priv.q)


def test_hevr_encrypts_phe_decrypts(pheutil_keys, tmp_path):
    priv_path, pub_path = pheutil_keys
    pub, priv = _load(pub_path), _load(priv_path)
    phe_priv = _phe_private(priv_path)
    for m in VALUES:
        for c in (pub.encrypt(m), priv.encrypt(m)):
            enc = paillier.EncryptedNumber(phe_priv.public_key, int(c), exponent=0)
            assert phe_priv.decrypt(enc) == m
    total = pub.add(pub.encrypt(20), priv.encrypt(22))  # hevr's homomorphic sum, pheutil's decryption
    assert _pheutil_decrypt(priv_path, total, tmp_path) == "42"


def test_phe_encrypts_hevr_decrypts(pheutil_keys):
    priv_path, pub_path = pheutil_keys
    priv = _load(priv_path)
    phe_pub = command_line.load_public_key(json.loads(pub_path.read_text()))
    for m in VALUES:
        enc = phe_pub.encrypt(m)
        assert enc.exponent == 0 and priv.decrypt(enc.ciphertext()) == m
    # pheutil encrypt: fixed point with base 16, exponent -32
    out = json.loads(_pheutil("encrypt", str(pub_path), "--", "-12.5"))
    assert priv.decrypt(int(out["v"])) * 16.0 ** out["e"] == -12.5


def test_phe_reads_hevr_exported_keys(tmp_path, keypair512):
    pub, priv = keypair512
    priv.save(tmp_path / "k.json", format="phe")
    _pheutil("extract", str(tmp_path / "k.json"), str(tmp_path / "k.pub.json"))
    assert _load(tmp_path / "k.pub.json") == pub
    phe_priv = _phe_private(tmp_path / "k.json")
    assert phe_priv == paillier.PaillierPrivateKey(paillier.PaillierPublicKey(int(pub.n)), int(priv.p), int(priv.q))
    for m in VALUES:
        assert phe_priv.decrypt(paillier.EncryptedNumber(phe_priv.public_key, int(priv.encrypt(m)))) == m
    assert _pheutil_decrypt(tmp_path / "k.json", pub.encrypt(-77), tmp_path) == "-77"
    pub.save(tmp_path / "hevr.pub.json", format="phe")  # and pheutil encrypts with hevr's public file
    out = json.loads(_pheutil("encrypt", str(tmp_path / "hevr.pub.json"), "3"))
    assert priv.decrypt(int(out["v"])) == 3 * 16**32


def test_encrypted_volume_with_a_pheutil_key(tmp_path, pheutil_keys):
    priv_path, pub_path = pheutil_keys
    pub, priv = _load(pub_path), _load(priv_path)
    vol = hevr.phantom(8)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", pub, brick=4, progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=8, height=8)
    img = hevr.render(ev, cam, progress=False).decrypt(priv)
    ref = hevr.render_plain(vol, cam)
    assert img.shape == ref.shape and np.any(ref != 0)
    assert np.all(np.abs(img - ref) <= hevr.error_bound(ev, cam))


# -- phe 1.2 files: lambda and mu instead of p and q ---------------------------------------------


def _with_lambda(priv, lam) -> dict:
    """The private key's phe file with fields lambda = ``lam`` and mu = lam⁻¹ mod n added."""
    mu = gmpy2.invert(lam, priv.public_key.n)
    return {**phe_key_dict(priv), "lambda": int_to_base64(int(lam)), "mu": int_to_base64(int(mu))}


def _legacy(priv, lam) -> dict:
    """A private key as phe <= 1.2's pheutil wrote it: lambda and mu, no p and q (phe's own
    base64 helper)."""
    return {k: v for k, v in _with_lambda(priv, lam).items() if k not in ("p", "q")}


@pytest.mark.parametrize("form", ["phi", "lcm", "both"])
def test_lambda_mu_files_load(keypair, form):
    _, priv = keypair
    p, q = priv.p, priv.q
    lam = (p - 1) * (q - 1) if form != "lcm" else gmpy2.lcm(p - 1, q - 1)
    d = _with_lambda(priv, lam) if form == "both" else _legacy(priv, lam)
    back = key_from_phe_dict(d, "legacy.json")
    assert back == priv and (back.p, back.q) == (p, q)


def test_factor_from_a_multiple_of_lambda(keypair512):
    _, priv = keypair512
    n, lcm = priv.public_key.n, gmpy2.lcm(priv.p - 1, priv.q - 1)
    for m in (lcm, 3 * lcm, 97 * lcm):  # 97·lcm > n: Miller's randomized method
        assert factor_from_lambda(n, m) == (priv.p, priv.q)
    assert factor_from_lambda(n, lcm + 2) is None and factor_from_lambda(n, lcm + 1) is None


# -- hostile files -------------------------------------------------------------------------------


def _secrets(priv) -> list[str]:
    p, q = int(priv.p), int(priv.q)
    phi = (p - 1) * (q - 1)
    mu = int(gmpy2.invert(phi, p * q))
    out = []
    for x in (p, q, phi, mu, int(gmpy2.lcm(p - 1, q - 1))):
        out += [str(x), hex(x)[2:], int_to_base64(x)]
    return out


def _composite_factor_key(bits: int = 256) -> tuple[int, int, int]:
    """n = p·q of ``bits`` bits with q prime and p an odd composite, both of bits/2 bits."""
    q = int(gmpy2.prev_prime(2 ** (bits // 2)))
    p = 2 ** (bits // 2) - 3
    while is_probable_prime(p):
        p -= 2
    assert (p * q).bit_length() == bits
    return p * q, p, q


def _b64(x: int) -> str:
    return int_to_base64(x)


def _other_prime(priv) -> int:
    return int(gmpy2.next_prime(priv.p + 2))


HOSTILE = {
    # field presence and types
    "no pub": (lambda d, pr: _drop(d, "pub"), "field 'pub': expected a JSON object"),
    "pub not an object": (lambda d, pr: _set(d, pub=["n"]), "field 'pub': expected a JSON object"),
    "no p": (lambda d, pr: _drop(d, "p"), "field 'p': expected base64url"),
    "no q": (lambda d, pr: _drop(d, "q"), "field 'q': expected base64url .* got nothing"),
    "no n": (lambda d, pr: _set(d, pub=_drop(d["pub"], "n")), "field 'pub.n': expected base64url"),
    "no key_ops": (lambda d, pr: _drop(d, "key_ops"), "field 'key_ops': expected a list of strings with 'decrypt'"),
    "key_ops encrypt": (lambda d, pr: _set(d, key_ops=["encrypt"]), "field 'key_ops'"),
    "key_ops string": (lambda d, pr: _set(d, key_ops="decrypt"), "field 'key_ops'"),
    "pub key_ops": (lambda d, pr: _set(d, pub=_set(d["pub"], key_ops=["sign"])), "field 'pub.key_ops'"),
    "p as a number": (lambda d, pr: _set(d, p=int(pr.p)), "field 'p': expected base64url .* got a JSON int"),
    # kty / alg
    "wrong kty": (lambda d, pr: _set(d, kty="RSA"), "field 'kty': expected 'DAJ' .* got 'RSA'"),
    "kty not a string": (lambda d, pr: _set(d, kty=["DAJ"]), "field 'kty': expected 'DAJ' .* got a JSON list"),
    "wrong pub kty": (lambda d, pr: _set(d, pub=_set(d["pub"], kty="PAI")), "field 'pub.kty'"),
    "wrong alg": (lambda d, pr: _set(d, pub=_set(d["pub"], alg="PAI-GN2")), "field 'pub.alg': expected 'PAI-GN1'"),
    "no alg": (lambda d, pr: _set(d, pub=_drop(d["pub"], "alg")), "field 'pub.alg': expected 'PAI-GN1'.* nothing"),
    # base64url
    "standard base64": (
        lambda d, pr: _set(d, p=_b64(int(pr.p)).replace("-", "+").replace("_", "/") + "+/"),
        "field 'p': .* characters other than",
    ),
    "padding": (lambda d, pr: _set(d, q=_b64(int(pr.q)) + "=="), "field 'q': .* characters other than"),
    "non-ASCII": (lambda d, pr: _set(d, p="é" + _b64(int(pr.p))[1:]), "field 'p': .* characters other than"),
    "length 1 mod 4": (lambda d, pr: _set(d, p="A" * 41), "field 'p': .* length of 1 modulo 4"),
    "empty": (lambda d, pr: _set(d, q=""), "field 'q': .* got 0 characters"),
    "zero": (lambda d, pr: _set(d, p="AAAA"), "field 'p': .* an encoding of zero"),
    "too long": (lambda d, pr: _set(d, p="A" * 1000), "field 'p': .* got 1000 characters"),
    # consistency and sizes
    "p swapped": (lambda d, pr: _set(d, p=_b64(_other_prime(pr))), "p·q does not equal n"),
    "n of another key": (
        lambda d, pr: _set(d, pub=_set(d["pub"], n=_b64(int(pr.public_key.n) + 2))),
        "p·q does not equal n",
    ),
    "p equals q": (lambda d, pr: _set(d, p=d["q"]), "p·q does not equal n"),
    "n too small": (lambda d, pr: _set(d, pub=_set(d["pub"], n=_b64(2**61 + 1))), "field 'pub.n': expected an even"),
    "n odd bits": (lambda d, pr: _set(d, pub=_set(d["pub"], n=_b64(2**300 + 1))), r"got 301 bits"),
    "n too large": (lambda d, pr: _set(d, pub=_set(d["pub"], n=_b64(2**MAX_BITS + 1))), "field 'pub.n': expected"),
    "lambda wrong": (lambda d, pr: _legacy(pr, (pr.p - 1) * (pr.q - 1) + 2), "field 'lambda': expected"),
    "lambda odd": (lambda d, pr: _legacy(pr, (pr.p - 1) * (pr.q - 1) + 1), "field 'lambda': expected"),
    "mu wrong": (lambda d, pr: _set(_legacy(pr, (pr.p - 1) * (pr.q - 1)), mu=_b64(12345)), "field 'mu': expected"),
    "no mu": (lambda d, pr: _drop(_legacy(pr, (pr.p - 1) * (pr.q - 1)), "mu"), "field 'mu': expected base64url"),
    "lambda >= n": (
        lambda d, pr: _set(_legacy(pr, 1), **{"lambda": _b64(int(pr.public_key.n) + 4)}),
        "field 'lambda': expected a value below n",
    ),
    "lambda disagrees with p, q": (
        lambda d, pr: _with_lambda(pr, (pr.p - 1) * (pr.q - 1) + 2),
        "field 'lambda': expected a multiple of lcm",
    ),
}


def _drop(d: dict, *names: str) -> dict:
    return {k: v for k, v in d.items() if k not in names}


def _set(d: dict, **kw) -> dict:
    return {**d, **kw}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_phe_files(tmp_path, keypair256, case):
    _, priv = keypair256
    mutate, needle = HOSTILE[case]
    path = tmp_path / "k.json"
    path.write_text(json.dumps(mutate(phe_key_dict(priv), priv), ensure_ascii=False), encoding="utf-8")
    with pytest.raises(hevr.InvalidKeyError) as info:
        _load(path)
    msg = str(info.value)
    assert msg.startswith(f"key file {path}")
    assert re.search(needle, msg), msg
    assert not any(s in msg for s in _secrets(priv)), msg


def test_composite_factor_is_refused(tmp_path):
    n, p, q = _composite_factor_key(256)
    d = {
        "kty": "DAJ",
        "key_ops": ["decrypt"],
        "p": _b64(p),
        "q": _b64(q),
        "pub": {"kty": "DAJ", "alg": "PAI-GN1", "key_ops": ["encrypt"], "n": _b64(n)},
    }
    (tmp_path / "k.json").write_text(json.dumps(d))
    with pytest.raises(hevr.InvalidKeyError, match="p or q is not prime") as info:
        _load(tmp_path / "k.json")
    assert str(p) not in str(info.value) and _b64(p) not in str(info.value)


def test_huge_and_odd_phe_files(tmp_path):
    path = tmp_path / "k.json"
    path.write_text(json.dumps({"kty": "DAJ", "kid": "x" * MAX_KEY_FILE_BYTES}))
    with pytest.raises(hevr.InvalidKeyError, match=f"expected at most {MAX_KEY_FILE_BYTES} bytes"):
        _load(path)
    path.write_text(json.dumps({"kty": "DAJ", "alg": "PAI-GN1"}))
    with pytest.raises(hevr.InvalidKeyError, match="field 'n': expected base64url .* got nothing"):
        _load(path)
    with pytest.raises(hevr.InvalidKeyError, match="expected a JSON object, got a JSON list"):
        key_from_phe_dict(["kty"], "mem")
