"""The CUDA kernel source's arithmetic, compiled for the host, against gmpy2 (issue 14's
"correctness without a GPU in CI"): Montgomery products at every size hevr uses (n² of 1024-,
2048-bit keys; p² of the owner path; small moduli), random operands and the edge cases — 0, 1,
N−1, operands with every limb 0xffffffff, and carries through every limb."""

from __future__ import annotations

import secrets
import shutil
import subprocess

import gmpy2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hevr import MissingDependencyError, ParameterError
from hevr.backends.cuda import (
    HostMontgomery,
    build_host,
    from_limbs,
    montgomery_params,
    to_limbs,
)
from hevr.backends.cuda import host as host_module
from hevr.backends.cuda.launch import HostLauncher
from hevr.backends.cuda.residues import Modulus


def _odd_modulus(bits: int) -> int:
    return secrets.randbits(bits) | (1 << (bits - 1)) | 1


def _mont(a: int, b: int, n: int) -> int:
    """The reference: a·b·R^-1 mod n with gmpy2."""
    nl = -(-n.bit_length() // 32)
    r_inv = gmpy2.invert(gmpy2.mpz(1) << (32 * nl), n)
    return int(gmpy2.mpz(a) * b * r_inv % n)


@pytest.fixture(scope="module")
def lib():
    return build_host()


@pytest.mark.parametrize("bits", [33, 64, 96, 512, 1024, 2048, 4095, 4096])
def test_random_products_match_gmpy2(lib, bits):
    n = _odd_modulus(bits)
    m = HostMontgomery(n)
    a = [secrets.randbelow(n) for _ in range(64)]
    b = [secrets.randbelow(n) for _ in range(64)]
    assert m.mont_mul(a, b) == [_mont(x, y, n) for x, y in zip(a, b)]
    assert m.modmul(a, b) == [int(gmpy2.mpz(x) * y % n) for x, y in zip(a, b)]
    assert m.from_mont(m.to_mont(a)) == a


@pytest.mark.parametrize("bits", [64, 2048, 4096])
def test_edge_operands(lib, bits):
    n = _odd_modulus(bits)
    m = HostMontgomery(n)
    nl = m.nl
    edges = [0, 1, 2, n - 1, n - 2, (n - 1) // 2, n // 2 + 1]
    edges += [(1 << (32 * k)) - 1 for k in range(1, nl) if (1 << (32 * k)) - 1 < n]  # all-ones low limbs
    edges += [1 << (32 * k) for k in range(1, nl) if (1 << (32 * k)) < n]  # a carry into every limb
    edges += [n - (1 << (32 * k)) for k in range(0, nl) if (1 << (32 * k)) < n]
    pairs = [(x, y) for x in edges for y in edges]
    a, b = [x for x, _ in pairs], [y for _, y in pairs]
    assert m.mont_mul(a, b) == [_mont(x, y, n) for x, y in pairs]


def test_moduli_with_extreme_limbs(lib):
    """All-ones moduli (every reduction carries) and 2^(32k) + 1 (sparse limbs)."""
    for n in [(1 << 4096) - 1, (1 << 2048) - 1, (1 << 1024) + 1, (1 << 64) + 1, (1 << 4095) + 1, 3]:
        m = HostMontgomery(n)
        vals = [0, 1, n - 1, n // 3, secrets.randbelow(n), secrets.randbelow(n)]
        a = [x for x in vals for _ in vals]
        b = [y for _ in vals for y in vals]
        assert m.mont_mul(a, b) == [_mont(x, y, n) for x, y in zip(a, b)]


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 4096).map(lambda b: (1 << (b - 1)) | 1), st.data())
def test_modmul_property(lib, n_base, data):
    n = n_base | data.draw(st.integers(0, n_base - 1)) | 1
    x = data.draw(st.integers(0, n - 1))
    y = data.draw(st.integers(0, n - 1))
    m = HostMontgomery(n)
    assert m.modmul([x], [y]) == [x * y % n]


def test_limb_conversion_and_parameters():
    vals = [0, 1, (1 << 64) - 1, 1 << 95]
    assert from_limbs(to_limbs(vals, 3)) == vals
    n = _odd_modulus(2048)
    nl, ninv, r2 = montgomery_params(n)
    assert nl == 64 and (n * ninv) % (1 << 32) == (1 << 32) - 1 and r2 == pow(1 << 2048, 2, n)
    for bad, words in [(10, "odd modulus"), (1, "odd modulus"), ((1 << 4097) + 1, "at most 4096 bits")]:
        with pytest.raises(ParameterError, match=words):
            montgomery_params(bad)
    m = HostMontgomery(1_000_003)
    with pytest.raises(ParameterError, match=r"a: expected operands in \[0, n\)"):
        m.mont_mul([1_000_003], [1])
    with pytest.raises(ParameterError, match="b: expected 1 operands"):
        m.mont_mul([1], [1, 2])


def test_a_missing_compiler_is_named(monkeypatch, tmp_path):
    monkeypatch.setattr(host_module, "_LIB", {})
    monkeypatch.setattr(host_module, "SOURCE", tmp_path / "mont.cuh")
    (tmp_path / "mont.cuh").write_text("int x(void) { return 0; }\n")
    with pytest.raises(MissingDependencyError, match="compiler"):
        build_host(compiler=str(tmp_path / "no-such-cc"))


@pytest.mark.skipif(shutil.which("nvcc") is None, reason="nvcc (CUDA toolkit) is not installed: device compile check")
def test_source_compiles_for_the_device(tmp_path):
    """The same source builds as CUDA device code (sm_90, Hopper) — a compile check, no GPU needed."""
    run = subprocess.run(
        ["nvcc", "-x", "cu", "-arch=sm_90", "-c", str(host_module.SOURCE), "-o", str(tmp_path / "m.o")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-2000:]


@pytest.mark.parametrize("bits", [2017, 2048, 4065, 4096])  # 64 and 128 limbs: the sizes the experiment takes
def test_register_cios_experiment_matches_gmpy2(bits):
    """mont.cuh's HEVR_CIOS_REG body (an experiment ``hevr bench --gpu`` times on a device) against
    gmpy2: random operands and every edge case of test_edge_operands, as both factors."""
    launcher = HostLauncher(defines=("HEVR_CIOS_REG",))
    assert launcher.lib.hevr_experiment_cios_reg() == 1  # compiled in (the default build has no such symbol)
    assert not hasattr(HostLauncher().lib, "hevr_experiment_cios_reg")
    n = _odd_modulus(bits)
    M = Modulus(n)
    edges = [0, 1, 2, n - 1, n - 2, (n - 1) // 2, n // 2 + 1]
    edges += [(1 << (32 * k)) - 1 for k in range(1, M.nl) if (1 << (32 * k)) - 1 < n][::7]
    edges += [n - (1 << (32 * k)) for k in range(M.nl) if (1 << (32 * k)) < n][::7]
    a = edges + [secrets.randbelow(n) for _ in range(64)] + [(1 << (32 * M.nl)) - 1]  # a may reach R - 1
    for b in edges + [secrets.randbelow(n)]:
        got = from_limbs(launcher.mont_convert(to_limbs(a, M.nl), to_limbs([b], M.nl)[0], M))
        assert got == [_mont(x, b, n) for x in a], b
    with pytest.raises(ParameterError, match="defines: expected preprocessor names"):
        host_module.build_library(host_module.SOURCE, (), defines=("X=1; rm -rf /",))
