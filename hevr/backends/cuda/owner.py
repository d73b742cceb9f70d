"""Owner-side encryption on the kernels (``owner.cuh``): tables, exponents, one launch per batch.

The kernel makes exactly the CPU path's ciphertexts (:mod:`hevr.crypto.owner`) from the same
fixed-base tables, given the same exponents; so its distribution is the one proved there.

* **Tables.** :meth:`hevr.crypto.owner.OwnerEncryptor.tables` gives, per prime square, the rows
  ``G^(d·2^(w·i))``; they are converted once per key and process to limbs in Montgomery form
  (through the launcher's own ``mont_convert``) and kept for the two most recent keys, like the
  CPU path's tables — secret-derived, so only in the owner's encryption processes, never in a
  store, a log or a task graph (the key travels pickled to the owner's workers as before).
* **Exponents.** ``a``, ``b`` uniform in ``[0, p − 1)``, ``[0, q − 1)`` from :func:`os.urandom` in
  bulk (rejection sampling on ``bits(p − 1)``-bit draws: at least half are kept, since p − 1 has
  its top bit set), never from a GPU PRNG.
* **Mantissas** as signed 64-bit integers; anything else (Python integers beyond 2^63, or
  ``unsafe_no_obfuscation``) goes the CPU way, as do keys without tables.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...crypto.paillier import raw_encode_signed
from ...runtime.recent import Recent
from .host import MAX_LIMBS, from_limbs, to_limbs
from .residues import Modulus

__all__ = [
    "DecryptTables",
    "OwnerTables",
    "decrypt_limbs",
    "decrypt_tables",
    "owner_limbs",
    "owner_tables",
    "public_limbs",
    "random_below",
]

_CACHE = Recent(2)  # n -> OwnerTables
_DCACHE = Recent(2)  # n -> DecryptTables


@dataclass(repr=False)
class Half:
    """One prime square's table: ``T`` ``(rows·2^w, nl)`` uint32 in Montgomery form mod ``P.n``,
    ``NR`` = (n mod P)·R mod P, exponents below ``bound``."""

    P: Modulus
    T: np.ndarray
    rows: int
    w: int
    NR: np.ndarray
    bound: int


@dataclass(repr=False)
class OwnerTables:
    """Both halves, ``INV`` = (q²)^-1 mod p², and ``NL`` limbs of n² (a ciphertext)."""

    p: Half
    q: Half
    INV: np.ndarray
    NL: int
    device: dict = field(default_factory=dict)  # a device launcher's copies of the arrays

    def __repr__(self) -> str:  # secret-derived: say what it is, never what it holds
        return f"OwnerTables(<secret>, {32 * self.NL}-bit ciphertexts)"


def random_below(bound: int, count: int) -> np.ndarray:
    """``count`` integers uniform in ``[0, bound)`` as ``(count, ew)`` little-endian uint32 words,
    from :func:`os.urandom` (rejection sampling on ``bits(bound)``-bit draws).

    >>> r = random_below(1000, 500)
    >>> r.shape, bool((r[:, 0] < 1000).all()), len(set(r[:, 0].tolist())) > 300
    ((500, 1), True, True)
    """
    k = int(bound).bit_length()
    ew = max(1, -(-k // 32))
    B = to_limbs([int(bound)], ew)[0]
    top = k - 32 * (ew - 1)
    out = np.empty((count, ew), np.uint32)
    todo = np.arange(count)
    while todo.size:
        r = np.frombuffer(os.urandom(4 * ew * todo.size), "<u4").reshape(todo.size, ew).astype(np.uint32)
        if top < 32:
            r[:, -1] &= np.uint32((1 << top) - 1)
        less, decided = np.zeros(todo.size, bool), np.zeros(todo.size, bool)
        for j in range(ew - 1, -1, -1):  # lexicographic r < B from the top word
            lt, gt = (r[:, j] < B[j]) & ~decided, (r[:, j] > B[j]) & ~decided
            less |= lt
            decided |= lt | gt
        out[todo[less]] = r[less]
        todo = todo[~less]
    return out


def owner_tables(key: Any, launcher: Any) -> OwnerTables | None:
    """The kernel's tables for a :class:`hevr.PrivateKey` (cached per key), None without tables."""
    n = int(key.public_key.n)
    got = _CACHE.find(n)
    if got is not None:
        return got
    spec = key.owner.tables()
    if spec is None:
        return None
    halves = []
    for P2, n_mod, w, rows in spec[:2]:
        M = Modulus(int(P2))
        flat = [int(e) for row in rows for e in row]  # rows of 2^w entries; entry 0 is 1
        T = launcher.host(launcher.mont_convert(to_limbs(flat, M.nl), M.r2, M))  # numpy: any launcher's
        NR = to_limbs([int(n_mod) * (1 << (32 * M.nl)) % M.n], M.nl)[0]
        halves.append(Half(M, T, len(rows), int(w), NR, _bound(int(P2))))
    Mp = halves[0].P
    INV = to_limbs([int(spec[2]) % Mp.n], Mp.nl)[0]
    return _CACHE.keep(n, OwnerTables(halves[0], halves[1], INV, -(-(n * n).bit_length() // 32)))


def _bound(P2: int) -> int:
    """``p − 1`` from ``p²`` (an exact integer square root).

    >>> _bound(23 * 23)
    22
    """
    r = math.isqrt(P2)
    if r * r != P2:  # pragma: no cover - P2 is a prime's square
        raise ValueError("expected the square of a prime")
    return r - 1


def owner_limbs(launcher: Any, key: Any, mantissas: Any) -> Any:
    """Ciphertexts of ``mantissas`` under the private ``key`` as ``(m, NL)`` normal-form limbs in the
    launcher's arrays (on a device, a device array: ``launcher.host`` downloads it), or None where the
    kernel path does not apply (module docstring): the caller encrypts on the CPU."""
    x = np.asarray(mantissas)
    if not _kernel_sized(x, int(key.public_key.n)):
        return None
    tables = owner_tables(key, launcher)
    if tables is None:
        return None
    x = np.ascontiguousarray(x.reshape(-1), dtype=np.int64)
    if x.size:  # the CPU path's rule, and its error, for the largest magnitudes (|x| < n // 3)
        for v in (int(x.min()), int(x.max())):
            raw_encode_signed(v, key.public_key.n)
    a, b = random_below(tables.p.bound, x.size), random_below(tables.q.bound, x.size)
    return launcher.owner_encrypt(x, a, b, tables)


@dataclass(repr=False)
class DecryptHalf:
    """One prime of CRT decryption: its square ``P2`` and the prime ``P`` (Montgomery constants),
    the exponent ``E`` = p − 1 as words, ``PINV`` = p^-1 mod 2^(32k) (the exact division by p),
    ``HR`` = h_p·R mod p."""

    P2: Modulus
    P: Modulus
    E: np.ndarray
    PINV: np.ndarray
    HR: np.ndarray


@dataclass(repr=False)
class DecryptTables:
    """Both primes, ``PIQ`` = p^-1 mod q, ``NL`` limbs of n², ``nlo`` limbs of n."""

    p: DecryptHalf
    q: DecryptHalf
    PIQ: np.ndarray
    NL: int
    nlo: int
    device: dict = field(default_factory=dict)

    def __repr__(self) -> str:  # p − 1, p^-1, h_p: secret
        return f"DecryptTables(<secret>, {32 * self.nlo}-bit n)"


def decrypt_tables(key: Any) -> DecryptTables:
    """The CRT constants of a :class:`hevr.PrivateKey` as limbs (cached per key and process)."""
    n = int(key.public_key.n)
    got = _DCACHE.find(n)
    if got is not None:
        return got
    p, q, hp, hq, piq = (int(v) for v in key.crt_constants())
    halves = []
    for prime, h in ((p, hp), (q, hq)):
        P2, P = Modulus(prime * prime), Modulus(prime)
        k = P.nl
        E = to_limbs([prime - 1], -(-(prime - 1).bit_length() // 32))[0]
        PINV = to_limbs([pow(prime, -1, 1 << (32 * k))], k)[0]
        HR = to_limbs([h * (1 << (32 * k)) % prime], k)[0]
        halves.append(DecryptHalf(P2, P, E, PINV, HR))
    Q = halves[1].P
    tables = DecryptTables(
        halves[0], halves[1], to_limbs([piq % q], Q.nl)[0], -(-(n * n).bit_length() // 32), -(-n.bit_length() // 32)
    )
    return _DCACHE.keep(n, tables)


def _kernel_sized(x: np.ndarray, n: int) -> bool:
    """Whether the kernels take these mantissas under modulus ``n``: integers within int64, and
    n² within the kernels' limbs (a 4096-bit key's ciphertexts do not fit: the CPU path).

    >>> _kernel_sized(np.array([1, -2]), 2**2047), _kernel_sized(np.array([1]), 2**4095)
    (True, False)
    """
    if -(-(n * n).bit_length() // 32) > MAX_LIMBS:
        return False
    return x.dtype.kind in "iu" and not (x.dtype.kind == "u" and x.size and int(x.max()) >= 1 << 63)


def decrypt_limbs(launcher: Any, key: Any, limbs: np.ndarray) -> list[int]:
    """Residues ``m`` in ``[0, n)`` of normal-form ciphertext limbs ``(m, NL)`` (CRT, ``owner.cuh``)."""
    tables = decrypt_tables(key)
    c = np.zeros((limbs.shape[0], tables.NL), np.uint32)
    w = min(limbs.shape[1], tables.NL)
    c[:, :w] = limbs[:, :w]
    return from_limbs(launcher.decrypt(c, tables))


def public_limbs(launcher: Any, key: Any, mantissas: Any) -> Any:
    """Ciphertexts of ``mantissas`` under the public ``key`` as ``(m, NL)`` normal-form limbs in the
    launcher's arrays —
    ``(1 + x·n)·r^n mod n²``, ``r`` uniform in ``Z_n^*`` from :func:`os.urandom` (``r = 0`` and
    ``gcd(r, n) ≠ 1`` redrawn, as :class:`hevr.PublicKey` does) — or None where the kernel path
    does not apply (mantissas beyond int64): the caller encrypts on the CPU."""
    x = np.asarray(mantissas)
    if not _kernel_sized(x, int(key.n)):
        return None
    x = np.ascontiguousarray(x.reshape(-1), dtype=np.int64)
    n = int(key.n)
    if x.size:
        for v in (int(x.min()), int(x.max())):
            raw_encode_signed(v, key.n)
    r = random_below(n, x.size)
    k = -(-n.bit_length() // 32)
    r = np.pad(r, ((0, 0), (0, k - r.shape[1]))) if r.shape[1] < k else r
    ints = from_limbs(r)
    product = 1
    for v in ints:  # one gcd for the batch: Π r mod n shares a factor with n iff some r does (or is 0)
        product = product * v % n
    if math.gcd(product, n) != 1:  # about 2/sqrt(n) per value: in practice never; then value by value
        for i, v in enumerate(ints):
            while v == 0 or math.gcd(v, n) != 1:
                v = from_limbs(random_below(n, 1))[0]
                r[i] = to_limbs([v], k)[0]
    return launcher.public_encrypt(x, np.ascontiguousarray(r), to_limbs([n], k)[0], Modulus(n * n))
