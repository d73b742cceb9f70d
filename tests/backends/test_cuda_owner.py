"""The key holder's kernels (hevr/backends/cuda/owner.cuh, owner.py), run as ``cuda-host``.

Owner-side encryption: given the same exponents it makes the CPU path's exact ciphertexts; its
ciphertexts decrypt exactly (edge mantissas, 64–2048-bit keys); its masks are n-th residues drawn
uniformly from the right subgroup (a tiny key, every element hit); exponents come uniformly from
os.urandom; magnitudes the CPU path refuses are refused with its error; what it does not take goes
the CPU way. CRT decryption: the CPU backend's residues for values in (0, n²) coprime to n (every
ciphertext is; random values are, but for a chance of about 2/sqrt(n)) and for encryptions.
Unbalanced primes (p² and q² of different limb counts, p < 2^16) and the secrecy of the tables'
reprs are checked too. ``HEVR_TEST_KERNELS=cuda`` runs it on a GPU."""

from __future__ import annotations

import os
import secrets
import warnings
from types import SimpleNamespace

import gmpy2
import numpy as np
import pytest
from gmpy2 import mpz

import hevr
from hevr.backends import CpuBackend, get_backend
from hevr.backends.cuda import backend as backend_module
from hevr.backends.cuda import owner as owner_module
from hevr.backends.cuda.host import from_limbs
from hevr.backends.cuda.owner import owner_tables, random_below
from hevr.backends.cuda.residues import LimbBatch
from hevr.crypto.owner import OwnerEncryptor
from hevr.crypto.primes import random_prime_with_factors

KERNELS = os.environ.get("HEVR_TEST_KERNELS", "cuda-host")
BE, CPU = get_backend(KERNELS), CpuBackend()


@pytest.fixture(autouse=True)
def _keyholder_kernels(monkeypatch):
    """On a device these kernels are off by default (device.py); here they are the subject, for this
    module's tests only (the other kernel suites run the shipped setting)."""
    monkeypatch.setattr(BE._launch, "keyholder", True)


EDGES = np.array([0, 1, -1, 2, -2, 12345, -(2**31), 2**40, -(2**40), 2**62, 2**63 - 1, -(2**63)], np.int64)


def _edges(pub) -> np.ndarray:
    """EDGES within the key's signed range (|x| < n // 3: a 64-bit key takes 62-bit values)."""
    lim = int(pub.n) // 3 - 1
    return np.clip(EDGES, -min(lim, 2**63 - 1), min(lim, 2**63 - 1)).astype(np.int64)


def _key(bits):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        return hevr.generate_keypair(bits)


@pytest.mark.parametrize("bits", [64, 128, 256, 512])
def test_ciphertexts_decrypt_exactly(bits):
    pub, priv = _key(bits)
    lim = min(int(pub.n) // 3 - 1, 2**62)
    x = np.concatenate([_edges(pub), np.random.default_rng(bits).integers(-lim, lim, 200)])
    cts = BE.encrypt(priv, x)
    assert isinstance(cts, LimbBatch) and len(cts) == x.size
    assert BE.first_out_of_range(cts, pub.nsquare) is None
    assert BE.decrypt(priv, cts) == [int(v) % int(pub.n) for v in x.tolist()]
    assert len({bytes(r) for r in BE.to_bytes(cts, 2 * ((int(pub.n).bit_length() + 7) // 8))}) == x.size  # fresh masks


def test_ciphertexts_decrypt_exactly_at_2048_bits(keypair2048):
    pub, priv = keypair2048
    cts = BE.encrypt(priv, EDGES)
    assert BE.decrypt(priv, cts) == [int(v) % int(pub.n) for v in EDGES.tolist()]


@pytest.mark.parametrize("bits", [64, 512])
def test_same_exponents_give_the_cpu_path_s_ciphertext(bits):
    """c = c_q + q²·((c_p − c_q)·(q²)^-1 mod p²), c_p = (1 + x·n)·G_p^a mod p²: the CPU formula."""
    pub, priv = _key(bits)
    owner = priv.owner
    launcher = BE._launch
    tables = owner_tables(priv, launcher)
    x = np.concatenate([_edges(pub), np.arange(-50, 50)]).astype(np.int64)
    a, b = random_below(tables.p.bound, x.size), random_below(tables.q.bound, x.size)
    got = from_limbs(launcher.host(launcher.owner_encrypt(x, a, b, tables)))  # device arrays on a GPU
    hp, hq = owner._hp, owner._hq
    n = pub.n
    want = []
    for v, ea, eb in zip(x.tolist(), from_limbs(a), from_limbs(b)):
        m = mpz(v) % n
        cp = (1 + m * hp.n_mod) * hp.table.pow(ea) % hp.psquare
        cq = (1 + m * hq.n_mod) * hq.table.pow(eb) % hq.psquare
        want.append(int(cq + hq.psquare * ((cp - cq) * owner._q2_inv_p2 % hp.psquare)))
    assert got == want


def test_masks_are_nth_residues_and_cover_the_subgroup_on_a_tiny_key():
    """p = 23, q = 59: encryptions of 0 are masks; mod p² they must hit all 22 elements of H_p,
    each about equally often, and be exactly the textbook set {r^n mod p²}."""
    p, q = mpz(23), mpz(59)
    key = SimpleNamespace(public_key=SimpleNamespace(n=int(p * q)), owner=OwnerEncryptor(p, q))
    owner_module._CACHE.pop(int(p * q), None)
    cts = from_limbs(BE._launch.host(owner_module.owner_limbs(BE._launch, key, np.zeros(4000, np.int64))))
    n, n2, lam = p * q, (p * q) ** 2, (p - 1) * (q - 1)
    assert all(gmpy2.powmod(c, lam, n2) == 1 and gmpy2.gcd(c, n) == 1 for c in cts)  # n-th residues, units
    counts: dict[int, int] = {}
    for c in cts:
        counts[c % int(p * p)] = counts.get(c % int(p * p), 0) + 1
    assert set(counts) == {int(gmpy2.powmod(r, n, p * p)) for r in range(1, 23)}
    assert min(counts.values()) > 4000 / 22 * 0.6
    owner_module._CACHE.pop(int(p * q), None)


@pytest.mark.parametrize("bound", [1000, 2**32 - 1, 2**32, 2**32 + 1, 3 * 2**70 + 5])
def test_random_exponents_are_uniform_below_the_bound(bound):
    r = from_limbs(random_below(bound, 3000))
    assert all(0 <= v < bound for v in r)
    assert sum(v < bound // 2 for v in r) == pytest.approx(1500, abs=200)  # both halves, evenly
    assert len(set(r)) > 2900 or bound < 10_000


def test_what_the_kernel_does_not_take_goes_the_cpu_way(keypair256, monkeypatch):
    pub, priv = keypair256
    calls = []
    for name in ("owner_limbs", "public_limbs"):
        real = getattr(backend_module, name)
        monkeypatch.setattr(backend_module, name, lambda *a, _real=real, _name=name: calls.append(_name) or _real(*a))
    big = np.array([2**80, -(2**90), 3], dtype=object)  # beyond int64
    for key, values, kw, path in (
        (priv, big, {}, ["owner_limbs"]),
        (pub, big, {}, ["public_limbs"]),
        (priv, EDGES[:4], {"unsafe_no_obfuscation": True}, []),
        (priv, EDGES[:4], {}, ["owner_limbs"]),
        (pub, EDGES[:4], {}, ["public_limbs"]),
    ):
        calls.clear()
        cts = BE.encrypt(key, values, **kw)
        assert calls == path and BE.decrypt(priv, cts) == [int(v) % int(pub.n) for v in values.tolist()]
    assert owner_module.public_limbs(BE._launch, pub, big) is None
    four_k = SimpleNamespace(n=(1 << 4095) + 1, public_key=SimpleNamespace(n=(1 << 4095) + 1))
    assert owner_module.owner_limbs(BE._launch, four_k, EDGES) is None  # n² beyond the kernels' limbs
    assert owner_module.public_limbs(BE._launch, four_k, EDGES) is None
    assert owner_module.owner_limbs(BE._launch, priv, big) is None
    assert owner_module.owner_limbs(BE._launch, priv, np.array([2**63], np.uint64)) is None


def test_magnitudes_the_cpu_path_refuses_are_refused_alike():
    pub, priv = _key(64)
    lim = int(pub.n) // 3 - 1
    for bad in (lim + 1, -(lim + 1)):
        with pytest.raises(hevr.PlaintextOverflowError, match="below n // 3 for a 64-bit key") as kernel:
            BE.encrypt(priv, np.array([0, bad, 3], np.int64))
        with pytest.raises(hevr.PlaintextOverflowError) as cpu:
            CPU.encrypt(priv, np.array([0, bad, 3], np.int64))
        assert str(kernel.value) == str(cpu.value)


@pytest.mark.parametrize("bits", [64, 96, 256, 512, 1024])
def test_crt_decryption_gives_the_cpu_residues(bits):
    """Values in (0, n²) coprime to n — not only encryptions — decrypt to the CPU backend's residues."""
    pub, priv = _key(bits)
    n2 = int(pub.nsquare)
    W = 2 * ((int(pub.n).bit_length() + 7) // 8)
    vals = [1, 2, n2 - 1, n2 - 2] + [secrets.randbelow(n2 - 1) + 1 for _ in range(200)]
    rec = CPU.to_bytes(vals, W)
    assert BE.decrypt(priv, BE.from_bytes(rec)) == CPU.decrypt(priv, CPU.from_bytes(rec))
    mont = BE.segment_products(BE.from_bytes(rec), np.arange(len(vals) + 1), 1, n2)  # Montgomery form first
    assert BE.decrypt(priv, mont) == CPU.decrypt(priv, CPU.from_bytes(rec))
    assert BE.decrypt(priv, BE.from_bytes(np.zeros((0, W), np.uint8))) == []


def test_crt_decryption_at_2048_bits(keypair2048):
    pub, priv = keypair2048
    n2 = int(pub.nsquare)
    vals = [1, n2 - 1] + [secrets.randbelow(n2 - 1) + 1 for _ in range(20)]
    rec = CPU.to_bytes(vals, 512)
    assert BE.decrypt(priv, BE.from_bytes(rec)) == CPU.decrypt(priv, CPU.from_bytes(rec))


@pytest.mark.parametrize("bits", [64, 256, 512])
def test_public_key_encryption_decrypts_exactly_with_fresh_nth_residue_masks(bits):
    pub, priv = _key(bits)
    x = np.concatenate([_edges(pub), np.zeros(50, np.int64)])
    cts = BE.encrypt(pub, x)
    assert isinstance(cts, LimbBatch) and BE.decrypt(priv, cts) == [int(v) % int(pub.n) for v in x.tolist()]
    n, n2, lam = mpz(pub.n), mpz(pub.nsquare), (priv.p - 1) * (priv.q - 1)
    W = 2 * ((int(n).bit_length() + 7) // 8)
    zeros = [int(v) for v in CPU.from_bytes(BE.to_bytes(cts, W))[-50:]]  # the encryptions of 0: r^n
    assert all(gmpy2.powmod(c, lam, n2) == 1 and gmpy2.gcd(c, n) == 1 for c in zeros)  # E(0) = r^n: n-th residues
    assert len(set(zeros)) == 50
    lim = int(pub.n) // 3 - 1
    if lim < 2**63 - 1:
        with pytest.raises(hevr.PlaintextOverflowError):
            BE.encrypt(pub, np.array([lim + 1], np.int64))


@pytest.mark.timeout(60)
@pytest.mark.parametrize("pbits,qbits", [(16, 24), (20, 40), (32, 64), (33, 95), (60, 68)])
def test_unbalanced_primes(pbits, qbits):
    """p² and q² of different limb counts (and p < 2^16: p² in one limb): the kernels reduce with
    Montgomery steps whatever the sizes — encryption (owner, public key) and decryption agree with
    the CPU path (a subtraction loop here once ran about q²/p² times)."""
    p, q = random_prime_with_factors(pbits)[0], random_prime_with_factors(qbits)[0]
    pub = hevr.PublicKey(int(p * q))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        priv = hevr.PrivateKey(pub, int(p), int(q))
    x = np.concatenate([_edges(pub), np.arange(-20, 20)]).astype(np.int64)
    want = [int(v) % int(pub.n) for v in x.tolist()]
    W = 2 * ((int(pub.n).bit_length() + 7) // 8)
    for key in (priv, pub):
        cts = BE.encrypt(key, x)
        assert CPU.decrypt(priv, CPU.from_bytes(BE.to_bytes(cts, W))) == want
        assert BE.decrypt(priv, cts) == want


def test_the_tables_repr_holds_no_secret(keypair256):
    priv = keypair256[1]
    p, q, hp, hq, piq = (int(v) for v in priv.crt_constants())
    texts = [repr(owner_tables(priv, BE._launch)), repr(owner_module.decrypt_tables(priv))]
    texts += [repr(h) for h in (owner_tables(priv, BE._launch).p, owner_module.decrypt_tables(priv).q)]
    secrets_ = [p - 1, q - 1, p, q, hp, hq, piq] + [int(w) for w in owner_module.decrypt_tables(priv).p.E]
    for text in texts:
        assert "<secret>" in text or "object at" in text
        assert not any(str(v) in text for v in secrets_ if v > 1000), text
