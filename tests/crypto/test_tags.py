"""Linearly homomorphic tags (hevr.crypto.tags), end to end on real Paillier ciphertexts: honest
weighted sums always pass the one-ciphertext check; a changed sum, E(δ) multiplied into a tag sum,
another camera's weights, another store's tags, and a server that re-encrypts guessed values are
all caught. The β sums agree with exact Python integers (hypothesis)."""

from __future__ import annotations

import itertools
import secrets

import gmpy2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hevr.crypto.tags import (
    BLOCK,
    TagKey,
    betas,
    coefficients,
    generate_tag_key,
    raw_check,
    raw_tags,
    weighted_beta_sums,
)

V = 300


def _rows(seed: int, rows: int = 40, per: int = 12, wmax: int = 1000):
    rng = np.random.default_rng(seed)
    vox = np.concatenate([rng.choice(V, per, replace=False) for _ in range(rows)])
    w = rng.integers(1, wmax, vox.size)
    return np.arange(rows + 1) * per, vox, w


def _power_sums(cts, indptr, vox, w, n2):
    """Π_j c_{v_j}^{w_j} per row (what the server computes, textbook)."""
    return [int(_prod(cts, vox[a:b], w[a:b], n2)) for a, b in itertools.pairwise(indptr)]


def _prod(cts, vox, w, n2):
    acc = gmpy2.mpz(1)
    for v, x in zip(vox.tolist(), w.tolist()):
        acc = acc * gmpy2.powmod(cts[v], x, n2) % n2
    return acc


@pytest.fixture(scope="module")
def scene(keypair256):
    pub, priv = keypair256
    key = generate_tag_key(pub.n)
    m = np.random.default_rng(1).integers(-500, 500, V)
    beta = betas(key, "store-a", "scalar", 0, 0, np.arange(V))
    residues = [int(x) % int(pub.n) for x in m.tolist()]
    cts = [priv.encrypt(int(x)) for x in m.tolist()]
    tags = priv.owner.encrypt_residues([gmpy2.mpz(t) for t in raw_tags(key, residues, beta)])  # residues of Z_n
    return pub, priv, key, m, beta, cts, tags


def _frame(scene, indptr, vox, w, *, cts=None, tags=None, beta_for_client=None, tamper=None):
    """Server: ray sums and tag sums; client: decrypt the sums, draw ρ, check one aggregate."""
    pub, priv, key, _, beta, c0, t0 = scene
    n2 = int(pub.nsquare)
    S_ct = _power_sums(cts or c0, indptr, vox, w, n2)
    T_ct = _power_sums(tags or t0, indptr, vox, w, n2)
    if tamper:
        S_ct, T_ct = tamper(S_ct, T_ct)
    sums = [priv.decrypt(c) for c in S_ct]  # what the image says
    rho = coefficients(secrets.token_bytes(32), len(sums))  # drawn after the image arrived
    agg = gmpy2.mpz(1)
    for t, r in zip(T_ct, rho):
        agg = agg * gmpy2.powmod(t, r, n2) % n2
    B = weighted_beta_sums(beta if beta_for_client is None else beta_for_client, indptr, vox, w)
    return raw_check(key, sums, B, rho, int(priv.raw_decrypt(agg))), sums


def test_honest_sums_pass_and_are_right(scene):
    indptr, vox, w = _rows(2)
    ok, sums = _frame(scene, indptr, vox, w)
    m = scene[3]
    assert ok and sums == [int(np.dot(m[vox[a:b]], w[a:b])) for a, b in itertools.pairwise(indptr)]


@pytest.mark.parametrize("attack", ["sum+1", "E(delta) in both", "swap two rays", "replace a ray"])
def test_altered_sums_are_caught(scene, attack):
    pub = scene[0]
    n2, g = int(pub.nsquare), int(pub.n) + 1
    indptr, vox, w = _rows(3)

    def tamper(S, T):
        S, T = list(S), list(T)
        if attack == "sum+1":
            S[5] = S[5] * g % n2  # E(S + 1): decrypts in range, looks plausible
        elif attack == "E(delta) in both":
            S[5] = S[5] * pow(g, 7, n2) % n2
            T[5] = T[5] * pow(g, 7, n2) % n2  # without α the tag cannot follow
        elif attack == "swap two rays":
            S[1], S[2] = S[2], S[1]
        else:
            S[0] = S[9]
        return S, T

    assert _frame(scene, indptr, vox, w, tamper=tamper)[0] is False


def test_another_camera_s_image_is_caught(scene):
    """The server renders other weights (another view); the client checks with its own."""
    indptr, vox, w = _rows(4)
    _, vox2, w2 = _rows(5)
    pub, priv, key, _, beta, cts, tags = scene
    n2 = int(pub.nsquare)
    S = _power_sums(cts, indptr, vox2, w2, n2)
    T = _power_sums(tags, indptr, vox2, w2, n2)
    sums = [priv.decrypt(c) for c in S]
    rho = coefficients(secrets.token_bytes(32), len(sums))
    agg = gmpy2.mpz(1)
    for t, r in zip(T, rho):
        agg = agg * gmpy2.powmod(t, r, n2) % n2
    assert not raw_check(key, sums, weighted_beta_sums(beta, indptr, vox, w), rho, int(priv.raw_decrypt(agg)))


def test_tags_of_another_store_and_guessed_reencryptions_are_caught(scene):
    pub, priv, key, m = scene[:4]
    indptr, vox, w = _rows(6)
    other_beta = betas(key, "store-b", "scalar", 0, 0, np.arange(V))  # same key, another store id
    other_tags = priv.owner.encrypt_residues(
        [gmpy2.mpz(t) for t in raw_tags(key, [int(x) % int(pub.n) for x in m.tolist()], other_beta)]
    )
    assert _frame(scene, indptr, vox, w, tags=other_tags)[0] is False
    # a server that re-encrypts values it guessed (here the true ones!) cannot make their tags
    guessed = [pub.encrypt(int(x)) for x in m.tolist()]
    fake_tags = [pub.encrypt(int(x) * 12345) for x in m.tolist()]
    assert _frame(scene, indptr, vox, w, cts=guessed, tags=fake_tags)[0] is False
    assert _frame(scene, indptr, vox, w, cts=guessed)[0] is True  # true values with the true tags: honest


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 30), st.integers(1, 60), st.integers(0, 2**31 - 1), st.integers(0, 2**32))
def test_weighted_beta_sums_are_exact(rows, per, wmax, seed):
    rng = np.random.default_rng(seed)
    limbs = rng.integers(0, 2**32, (50, 4), dtype=np.uint64).astype(np.uint32)
    sizes = rng.integers(0, per + 1, rows)
    indptr = np.concatenate([[0], np.cumsum(sizes)])
    vox = rng.integers(0, 50, int(indptr[-1]))
    w = rng.integers(0, wmax + 1, vox.size)
    vals = [int.from_bytes(r.astype("<u4").tobytes(), "little") for r in limbs]
    want = [sum(int(w[j]) * vals[int(vox[j])] for j in range(a, b)) for a, b in itertools.pairwise(indptr)]
    assert weighted_beta_sums(limbs, indptr, vox, w) == want


def test_betas_are_per_voxel_and_domain_separated():
    key = TagKey(1, bytes(range(32)), 35)
    idx = np.array([0, 1, BLOCK - 1, BLOCK, 3 * BLOCK + 7])
    full = betas(key, "s", "vector", 1, 2, np.arange(4 * BLOCK))
    assert (betas(key, "s", "vector", 1, 2, idx) == full[idx]).all()
    for other in (("t", "vector", 1, 2), ("s", "scalar", 1, 2), ("s", "vector", 0, 2), ("s", "vector", 1, 3)):
        assert not (betas(key, *other, idx) == full[idx]).all(axis=1).any()
    assert not (betas(TagKey(1, bytes(32), 35), "s", "vector", 1, 2, idx) == full[idx]).all(axis=1).any()
    assert len({tuple(r) for r in full.tolist()}) == full.shape[0]  # 128-bit values: no repeats
