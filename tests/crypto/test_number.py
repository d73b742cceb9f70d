"""Fixed-point encoding and encrypted floating point (fpAdd, fpMultiply, division)."""

from __future__ import annotations

from fractions import Fraction

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr
from hevr.crypto.encoding import decode, decode_exact, encode, reciprocal

FLOATS = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
EXPS = st.integers(min_value=-8, max_value=3)


@settings(max_examples=200, deadline=None)
@given(x=FLOATS)
def test_encode_decode_round_trip_exact(x):
    m, e = encode(x)
    assert decode(m, e) == x
    assert (m < 0) == (x < 0)


@settings(max_examples=200, deadline=None)
@given(x=FLOATS, e=st.integers(min_value=-9, max_value=0))
def test_encode_at_exponent_within_half_ulp(x, e):
    m, e2 = encode(x, e)
    assert e2 == e
    assert abs(decode_exact(m, e) - Fraction(x)) <= Fraction(1, 2) * Fraction(10) ** e
    if m != 0:
        assert (m < 0) == (x < 0)  # never silently flips the sign


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "3", None, True])
def test_encode_rejects(bad):
    with pytest.raises(hevr.ParameterError):
        encode(bad)


@settings(max_examples=60, deadline=None)
@given(a=FLOATS, b=FLOATS, ea=EXPS, eb=EXPS)
def test_fp_add_mixed_exponents(keypair256, a, b, ea, eb):
    pub, priv = keypair256
    x, y = pub.encrypt_number(a, ea), priv.encrypt_number(b, eb)
    s = x + y
    assert s.exponent == min(ea, eb)  # lowered, never raised
    ma, mb = encode(a, ea)[0], encode(b, eb)[0]
    expected = decode_exact(ma, ea) + decode_exact(mb, eb)
    assert decode_exact(priv.decrypt_number_mantissa(s), s.exponent) == expected
    d = x - y
    assert decode_exact(priv.decrypt_number_mantissa(d), d.exponent) == decode_exact(ma, ea) - decode_exact(mb, eb)


@settings(max_examples=60, deadline=None)
@given(a=FLOATS, k=st.one_of(st.integers(-(10**6), 10**6), FLOATS), ea=EXPS)
def test_fp_multiply_plain(keypair256, a, k, ea):
    pub, priv = keypair256
    x = pub.encrypt_number(a, ea)
    r = x * k
    ma = encode(a, ea)[0]
    mk, ek = encode(k)
    assert r.exponent == ea + ek
    assert decode_exact(priv.decrypt_number_mantissa(r), r.exponent) == decode_exact(ma, ea) * decode_exact(mk, ek)


def test_plain_add_and_negation(keypair256):
    pub, priv = keypair256
    x = pub.encrypt_number(2.5, -1)
    assert priv.decrypt_number(x + 1) == 3.5
    assert priv.decrypt_number(1 - x) == -1.5
    assert priv.decrypt_number(-x) == -2.5
    assert priv.decrypt_number(x * -0.125) == -0.3125


@settings(max_examples=80, deadline=None)
@given(
    a=st.integers(-(10**9), 10**9), d=st.one_of(st.integers(1, 10**6), st.floats(1e-3, 1e6)), digits=st.integers(1, 12)
)
def test_reciprocal_division_relative_error(keypair256, a, d, digits):
    pub, priv = keypair256
    q = pub.encrypt_number(a).divide(d, digits=digits)
    got = decode_exact(priv.decrypt_number_mantissa(q), q.exponent)
    exact = Fraction(a) / Fraction(d)
    if a == 0:
        assert got == 0
    else:
        assert abs(got - exact) / abs(exact) <= Fraction(1, 2) * Fraction(10) ** -digits


def test_reciprocal_rejects_zero_and_bad_digits():
    with pytest.raises(hevr.ParameterError, match="divisor"):
        reciprocal(0, 3)
    with pytest.raises(hevr.ParameterError, match="digits"):
        reciprocal(3, -1)


def test_decrease_exponent(keypair256):
    pub, priv = keypair256
    x = pub.encrypt_number(1.25, -2)
    y = x.decrease_exponent_to(-6)
    assert y.exponent == -6 and priv.decrypt_number(y) == 1.25
    with pytest.raises(hevr.ParameterError, match="new_exponent"):
        x.decrease_exponent_to(0)


def test_mixing_keys_is_refused(keypair256, keypair512):
    x = keypair256[0].encrypt_number(1)
    y = keypair512[0].encrypt_number(1)
    with pytest.raises(hevr.KeyMismatchError):
        x + y
    with pytest.raises(hevr.KeyMismatchError):
        keypair512[1].decrypt_number(x)


def test_fp_overflow_detected(keypair256):
    pub, priv = keypair256
    x = hevr.EncryptedNumber(pub, pub.encrypt(pub.max_int // 2 + 10), -3)
    # 3·(n/6) lands in the middle third of Z_n: detected, never decoded to garbage
    with pytest.raises(hevr.PlaintextOverflowError):
        priv.decrypt_number(x * 3)
    with pytest.raises(hevr.PlaintextOverflowError):
        priv.decrypt_number(x + x + x)


def test_repr_has_no_mantissa(keypair256):
    pub, _ = keypair256
    x = pub.encrypt_number(42)
    assert "42" not in repr(x).split("key=")[0]
