"""Issue 24 item 8: a key file's claims are validated — a public n that cannot be p·q, a file
that says "public" but holds private fields, a private key file others may read."""

from __future__ import annotations

import json
import os
import warnings

import gmpy2
import pytest

import hevr
from hevr.cli.main import main
from hevr.crypto.key_json import b64url as _b64url
from hevr.crypto.keyfile import modulus_problem
from hevr.errors import KeyFilePermissionWarning


def _load(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        return hevr.load_key(path)


def _secrets(priv) -> list[str]:
    return [str(int(priv.p)), str(int(priv.q)), _b64url(priv.p), _b64url(priv.q)]


def _public_file(path, n: int, fmt: str) -> None:
    if fmt == "hevr":
        d = {"format": "hevr-key", "version": 1, "kind": "public", "bits": int(n).bit_length(), "n": str(n)}
    else:
        d = {"kty": "DAJ", "alg": "PAI-GN1", "key_ops": ["encrypt"], "n": _b64url(n)}
    path.write_text(json.dumps(d))


def _bad_moduli(priv) -> dict[str, tuple[int, str]]:
    p, q = int(priv.p), int(priv.q)
    half = p.bit_length()
    prime = int(gmpy2.next_prime(p * q))
    while prime.bit_length() != 2 * half:  # pragma: no cover - p·q is not near a power of 2
        prime = int(gmpy2.next_prime(prime // 2))
    return {
        "even": (p * q + 1, "an even number"),
        "prime": (prime, "a prime"),
        "square": (p * p, "a perfect square"),
        "small factor": (3 * int(gmpy2.next_prime(p * q // 3)), "a multiple of the small prime 3"),
        "small factor 65521": (65521 * int(gmpy2.next_prime(p * q // 65521)), "a multiple of the small prime 65521"),
    }


@pytest.mark.parametrize("fmt", ["hevr", "phe"])
@pytest.mark.parametrize("case", ["even", "prime", "square", "small factor", "small factor 65521"])
def test_a_public_n_that_cannot_be_p_times_q_is_refused(tmp_path, keypair256, fmt, case):
    n, words = _bad_moduli(keypair256[1])[case]
    assert n.bit_length() == 256
    path = tmp_path / "k.pub.json"
    _public_file(path, n, fmt)
    with pytest.raises(
        hevr.InvalidKeyError,
        match=rf"^key file {path}: field 'n': expected a product of two "
        rf"distinct odd primes of 128 bits each, got {words}",
    ):
        _load(path)


def test_too_small_is_still_refused(tmp_path):
    path = tmp_path / "k.pub.json"
    _public_file(path, (1 << 61) + 1, "hevr")
    with pytest.raises(hevr.InvalidKeyError, match="n must have an even number of bits in"):
        _load(path)


@pytest.mark.parametrize("fmt", ["hevr", "phe"])
def test_valid_public_keys_still_load(tmp_path, keypair, fmt):
    pub, _ = keypair
    pub.save(tmp_path / "k.pub.json", format=fmt)
    assert _load(tmp_path / "k.pub.json") == pub
    assert modulus_problem(pub.n) is None


@pytest.mark.parametrize("extra", [["p"], ["p", "q"], ["q"], ["lambda"], ["mu"]])
def test_a_private_file_edited_to_say_public_is_refused(tmp_path, keypair256, extra):
    _, priv = keypair256
    d = priv.to_dict()
    d["kind"] = "public"
    d.update({"lambda": "12345", "mu": "678"})
    d = {k: v for k, v in d.items() if k not in {"p", "q", "lambda", "mu"} - set(extra)}
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d))
    os.chmod(path, 0o600)
    with pytest.raises(
        hevr.InvalidKeyError,
        match=rf"field 'kind': expected 'private' for a file holding the "
        rf"private fields? '{extra[0]}'.*got 'public'",
    ) as info:
        _load(path)
    assert not any(s in str(info.value) for s in _secrets(priv))


def test_a_file_that_says_private_must_hold_p_and_q(tmp_path, keypair256):
    pub, priv = keypair256
    d = pub.to_dict()
    d["kind"] = "private"
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d))
    with pytest.raises(hevr.InvalidKeyError, match="field 'p': expected a decimal string .* got nothing"):
        _load(path)


def test_phe_files_cannot_claim_public_while_holding_private_fields(tmp_path, keypair256):
    """pheutil files are told apart by their fields: private fields make a private key, which
    must then say decrypt and be whole."""
    _, priv = keypair256
    d = priv.to_dict(format="phe")
    d["key_ops"] = ["encrypt"]
    path = tmp_path / "k.json"
    path.write_text(json.dumps(d))
    with pytest.raises(hevr.InvalidKeyError, match="field 'key_ops': expected a list of strings with 'decrypt'"):
        _load(path)
    pub_d = dict(d["pub"], p=d["p"])  # a public key object carrying a private field
    path.write_text(json.dumps(pub_d))
    with pytest.raises(hevr.InvalidKeyError) as info:
        _load(path)
    assert not any(s in str(info.value) for s in _secrets(priv))


@pytest.mark.parametrize("fmt", ["hevr", "phe"])
@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660, 0o666])
def test_a_private_key_others_may_read_warns_like_openssh(tmp_path, keypair256, fmt, mode):
    _, priv = keypair256
    path = tmp_path / "key.json"
    priv.save(path, format=fmt)
    os.chmod(path, mode)
    with pytest.warns(
        KeyFilePermissionWarning,
        match=rf"UNPROTECTED PRIVATE KEY FILE: key file {path} has "
        rf"permissions {mode:04o}.*run: chmod 600 {path}",
    ) as rec:
        assert _load(path) == priv  # a warning, not a refusal (module docstring of hevr.crypto.keyfile)
    assert not any(s in str(w.message) for w in rec for s in _secrets(priv))


def test_owner_only_private_keys_and_public_keys_do_not_warn(tmp_path, keypair256):
    pub, priv = keypair256
    priv.save(tmp_path / "key.json")
    pub.save(tmp_path / "key.pub.json")  # 0644: public
    for mode in (0o600, 0o400):
        os.chmod(tmp_path / "key.json", mode)
        with warnings.catch_warnings():
            warnings.simplefilter("error", KeyFilePermissionWarning)
            _load(tmp_path / "key.json")
            _load(tmp_path / "key.pub.json")


def test_the_cli_shows_the_warning_and_keeps_working(tmp_path, keypair256, capsys):
    pub, priv = keypair256
    priv.save(tmp_path / "key.json")
    pub.save(tmp_path / "key.pub.json")
    os.chmod(tmp_path / "key.json", 0o644)
    assert main(["info", str(tmp_path / "key.json")]) == 0
    out, err = capsys.readouterr()
    assert "UNPROTECTED PRIVATE KEY FILE" in err and f"chmod 600 {tmp_path / 'key.json'}" in err
    assert main(["info", str(tmp_path / "key.pub.json")]) == 0
    assert "UNPROTECTED" not in capsys.readouterr().err
    _public_file(tmp_path / "even.pub.json", int(pub.n) + 1, "hevr")
    assert main(["info", str(tmp_path / "even.pub.json")]) != 0
    assert "field 'n'" in capsys.readouterr().err
