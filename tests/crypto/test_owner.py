"""Owner-side fast encryption: masks are n-th residues, generators are verified."""

from __future__ import annotations

import gmpy2
import pytest
from gmpy2 import mpz

from hevr.crypto import primes
from hevr.crypto.owner import OwnerEncryptor


def test_mask_is_nth_residue(keypair):
    pub, priv = keypair
    owner = priv.owner
    assert owner.uses_tables
    lam = (priv.p - 1) * (priv.q - 1)
    for _ in range(20):
        mask = owner.mask()
        # x is an n-th residue mod n² iff x^φ(n) ≡ 1 (mod n²) (the n-th residues form the
        # subgroup of order φ(n)); it must also be a unit.
        assert gmpy2.gcd(mask, pub.n) == 1
        assert gmpy2.powmod(mask, lam, pub.nsquare) == 1
        # and it encrypts zero
        assert priv.decrypt(mask) == 0


def test_generator_really_generates(keypair):
    _, priv = keypair
    for half in (priv.owner._hp, priv.owner._hq):
        p = half.p
        G = half.table._rows[0][1]
        # G has order exactly p-1 in (Z/p²)^*: G^(p-1) = 1 and G^((p-1)/ℓ) ≠ 1 for every ℓ
        assert gmpy2.powmod(G, p - 1, half.psquare) == 1
        factors = primes.factor_p_minus_1(p)
        assert factors is not None
        for ell in factors:
            assert gmpy2.powmod(G, (p - 1) // ell, half.psquare) != 1


def test_masks_cover_the_subgroup_uniformly_on_a_tiny_key():
    # p = 23, q = 59: H_p has p-1 = 22 elements; 4000 masks must hit every one of them
    # roughly equally often (a non-generator would only reach a proper subgroup).
    p, q = mpz(23), mpz(59)
    assert gmpy2.gcd(p * q, (p - 1) * (q - 1)) == 1
    owner = OwnerEncryptor(p, q)
    counts: dict[int, int] = {}
    for _ in range(4000):
        m = int(owner._hp.mask())
        counts[m] = counts.get(m, 0) + 1
    assert len(counts) == 22
    assert min(counts.values()) > 4000 / 22 * 0.6
    # the textbook set {r^n mod p² : r in Z_p^*} is exactly the same set
    n = p * q
    textbook = {int(gmpy2.powmod(r, n, p * p)) for r in range(1, 23)}
    assert set(counts) == textbook


def test_fallback_without_factorisation_is_exact(keypair256, monkeypatch):
    _, priv = keypair256
    monkeypatch.setattr("hevr.crypto.owner.factor_p_minus_1", lambda p: None)
    owner = OwnerEncryptor(priv.p, priv.q)
    assert not owner.uses_tables
    cs = owner.encrypt_residues([mpz(5), mpz(0)])
    assert priv.decrypt_array(cs) == [5, 0]


@pytest.mark.parametrize("bits", [16, 32, 48, 64, 128, 512])
def test_prime_generation_sizes_and_factors(bits):
    p, factors = primes.random_prime_with_factors(bits)
    assert p.bit_length() == bits and primes.is_probable_prime(p)
    m = p - 1
    for ell in factors:
        assert primes.is_probable_prime(ell)
        while m % ell == 0:
            m //= ell
    assert m == 1
