"""Raw Paillier layer and key-level operations: algebra, signed decoding, KAT."""

from __future__ import annotations

import gmpy2
import pytest
from gmpy2 import mpz
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr
from hevr.crypto import paillier as raw
from hevr.crypto.keys import PrivateKey, PublicKey

VALUES = st.integers(min_value=-(2**60), max_value=2**60)


def test_known_answer_tiny_primes_injected_r():
    # p = 7, q = 11, m = 42, r = 23: c = (1 + 42·77)·23^77 mod 77² = 3840 (checked by hand/Python ints)
    n = mpz(77)
    n2 = n * n
    c = raw.raw_obfuscate(raw.raw_encrypt_nude(42, n, n2), gmpy2.powmod(23, n, n2), n2)
    assert c == 3840
    priv = PrivateKey(PublicKey(77), 7, 11)
    assert priv.raw_decrypt(c) == 42


def test_known_answer_medium_primes():
    p, q = 1000003, 1000033
    n = mpz(p * q)
    n2 = n * n
    c = raw.raw_obfuscate(raw.raw_encrypt_nude(123456, n, n2), gmpy2.powmod(987654321, n, n2), n2)
    assert c == 95712476339733785605599
    assert PrivateKey(PublicKey(n), p, q).decrypt(c) == 123456


@settings(max_examples=40, deadline=None)
@given(a=VALUES, b=VALUES)
def test_add_sub(keypair256, a, b):
    pub, priv = keypair256
    ca, cb = pub.encrypt(a), priv.encrypt(b)
    assert priv.decrypt(pub.add(ca, cb)) == a + b
    assert priv.decrypt(pub.sub(ca, cb)) == a - b
    assert priv.decrypt(pub.neg(ca)) == -a


@settings(max_examples=40, deadline=None)
@given(a=VALUES, k=st.integers(min_value=-(2**40), max_value=2**40))
def test_mul_plain(keypair256, a, k):
    pub, priv = keypair256
    assert priv.decrypt(pub.mul(pub.encrypt(a), k)) == a * k


def test_mul_negative_uses_short_exponent(keypair256):
    pub, priv = keypair256
    c = pub.encrypt(9)
    # k ≡ -3 given as a residue mod n must take the inverse path and still be exact
    assert priv.decrypt(pub.mul(c, int(pub.n) - 3)) == -27
    assert priv.decrypt(pub.mul(c, 0)) == 0


def test_mul_rejects_float(keypair256):
    pub, _ = keypair256
    with pytest.raises(hevr.ParameterError, match="k must be an int"):
        pub.mul(pub.encrypt(1), 0.5)


def test_overflow_band_detected(keypair256):
    pub, priv = keypair256
    big = pub.max_int
    c = pub.encrypt(big)
    assert priv.decrypt(c) == big
    assert priv.decrypt(pub.encrypt(-big)) == -big
    with pytest.raises(hevr.PlaintextOverflowError):
        priv.decrypt(pub.add(c, c))
    with pytest.raises(OverflowError):  # also a builtin OverflowError
        priv.decrypt(pub.mul(c, 2))
    with pytest.raises(hevr.PlaintextOverflowError):
        pub.encrypt(big + 1)


def test_owner_and_public_ciphertexts_differ_and_decrypt(keypair):
    pub, priv = keypair
    for m in (0, 1, -1, 255, -(2**40)):
        c1, c2, c3 = pub.encrypt(m), priv.encrypt(m), priv.encrypt(m)
        assert len({int(c1), int(c2), int(c3)}) == 3
        assert priv.decrypt(c1) == priv.decrypt(c2) == priv.decrypt(c3) == m


@pytest.mark.parametrize("which", ["public", "private"])
def test_batch_round_trip(keypair, which):
    import numpy as np

    pub, priv = keypair
    values = np.arange(-60, 60, dtype=np.int16).reshape(4, 5, 6)
    key = pub if which == "public" else priv
    cs = key.encrypt_array(values)
    assert len(cs) == values.size
    assert priv.decrypt_array(cs) == values.ravel().tolist()


def test_unobfuscated_switch_is_deterministic_and_never_default(keypair256):
    pub, priv = keypair256
    a = pub.encrypt(7, unsafe_no_obfuscation=True)
    assert a == priv.encrypt(7, unsafe_no_obfuscation=True) == 1 + 7 * pub.n
    assert pub.encrypt(7) != a and priv.encrypt(7) != a
    assert priv.decrypt(a) == 7


def test_ciphertext_validation(keypair256):
    pub, priv = keypair256
    with pytest.raises(hevr.ParameterError):
        priv.decrypt(0)
    with pytest.raises(hevr.ParameterError):
        priv.decrypt(pub.nsquare)
    with pytest.raises(hevr.ParameterError, match="coprime"):
        pub.check_ciphertext(priv.p)
    pub.check_ciphertext(pub.encrypt(3))


def test_2048_bit_key_on_a_few_values(keypair2048):
    pub, priv = keypair2048
    assert pub.bits == 2048
    vals = [0, 1, -1, 12345, -(2**100)]
    cs = priv.encrypt_array(vals) + pub.encrypt_array(vals)
    assert priv.decrypt_array(cs) == vals + vals
    s = pub.add(pub.mul(cs[3], 1000), cs[2])
    assert priv.decrypt(s) == 12345 * 1000 - 1


@pytest.mark.parametrize("threads", [1, 2, 3, None])
def test_batched_crt_decryption_is_the_same(keypair512, threads):
    """raw_decrypt_crt_list (powmod_base_list on threads) gives raw_decrypt_crt's numbers, in order."""
    from hevr.crypto.paillier import raw_decrypt_crt, raw_decrypt_crt_list

    pub, priv = keypair512
    import random

    rng = random.Random(7)
    ms = [rng.randrange(int(pub.n) // 3) for _ in range(45)]
    cs = [priv.encrypt(m) for m in ms]
    args = (priv.p, priv.q, priv._psquare, priv._qsquare, priv._hp, priv._hq, priv._p_inv_q)
    got = raw_decrypt_crt_list(cs, *args, threads=threads)
    assert [int(g) for g in got] == [int(raw_decrypt_crt(c, *args)) for c in cs] == ms
    assert priv.decrypt_array(cs, signed=False) == ms
