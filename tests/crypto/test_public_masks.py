"""Public-key encryption with a fixed base and short exponents (hevr.crypto.public_masks,
issue 39, item 10): masks are n-th residues h^s, every ciphertext decrypts, randomness from secrets."""

from __future__ import annotations

import secrets

import gmpy2
import pytest
from gmpy2 import mpz
from hypothesis import given, settings
from hypothesis import strategies as st

from hevr.crypto import public_masks


def test_masks_are_h_to_a_short_secret_exponent(keypair, monkeypatch):
    pub, priv = keypair
    bits, table = public_masks._table(pub.n, pub.nsquare)
    assert bits == (int(pub.n).bit_length() + 1) // 2 and table.modulus == pub.nsquare
    h = table._rows[0][1]
    lam = (priv.p - 1) * (priv.q - 1)
    assert gmpy2.powmod(h, lam, pub.nsquare) == 1 and h != 1  # a random n-th residue, not 1
    drawn = []

    def randbits(k):
        drawn.append(k)
        return 0b1011 << (k - 4)

    monkeypatch.setattr(secrets, "randbits", randbits)  # the exponent comes from secrets
    mask = public_masks.public_mask(pub.n, pub.nsquare)
    assert drawn == [bits] and mask == gmpy2.powmod(h, 0b1011 << (bits - 4), pub.nsquare)
    assert priv.decrypt(mask) == 0  # a mask encrypts zero


def test_table_is_built_once_per_key_and_process(keypair):
    pub, _ = keypair
    first = public_masks._table(pub.n, pub.nsquare)
    assert public_masks._table(mpz(pub.n), pub.nsquare) is first
    masks = {public_masks.public_mask(pub.n, pub.nsquare) for _ in range(50)}
    assert len(masks) == 50  # fresh randomness every time


@settings(max_examples=200, deadline=None)
@given(st.integers(min_value=-(2**60), max_value=2**60))
def test_public_encryption_decrypts_any_value(keypair256, value):
    pub, priv = keypair256
    c = pub.encrypt(value)
    assert priv.decrypt(c) == value
    assert pub.encrypt(value) != c  # probabilistic


@pytest.mark.parametrize("bits", [512, 1024])
def test_public_arrays_decrypt_at_larger_keys(bits, keypair512):
    import warnings

    import hevr

    if bits == 512:
        pub, priv = keypair512
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
            pub, priv = hevr.generate_keypair(bits)
    values = [secrets.randbelow(int(pub.n) // 3) * (-1) ** i for i in range(40)] + [0, 1, -1]
    assert priv.decrypt_array(pub.encrypt_array(values)) == values
