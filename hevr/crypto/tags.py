"""Linearly homomorphic tags: the arithmetic of a verifiable render (issue 28).

The pure functions the verifiable path is built on, each tested against the textbook formula:
a store written with ``encrypt_volume(..., verifiable=True)`` holds a tag channel beside every
channel (:mod:`hevr.store.writer`), and :mod:`hevr.rendering.verify` renders and checks them.

The scheme
----------
The owner draws a tag key: α uniform in Z_n^* and a 256-bit PRF key k (both from
:mod:`secrets`, never stored on the server). Beside the ciphertext c_v = E(m_v) of every voxel v
(one per component of a channel, per pyramid level) the store would hold the tag

    t_v = E(α·m_v + β_v mod n),   β_v = PRF_k(store_id, channel, level, component, v) ∈ [0, 2^128).

A render applies public integer weights w_{r,v} (nearest counts, quantised trilinear weights)
to the voxels of ray r: S_r = Σ_v w_{r,v}·m_v. The same products on the tags give

    T_r = Π_v t_v^{w_{r,v}} = E(α·S_r + B_r),   B_r = Σ_v w_{r,v}·β_v   (all mod n),

and the client, who knows α, k and the public geometry, recomputes B_r in plaintext
(:func:`weighted_beta_sums`). One check per frame instead of one per ray: with coefficients
ρ_r (:func:`coefficients`), the server returns A = Π_r T_r^{ρ_r} and the client decrypts it once:

    D(A) ≡ α·Σ_r ρ_r·S'_r + Σ_r ρ_r·B_r   (mod n)        (:func:`raw_check`)

where S'_r are the sums the client decrypted from the image.

Soundness, informally. The server sees only ciphertexts (semantically secure under DCR), so α
and the β_v are hidden from it; whatever it returns, D(A) is a value it fixed by homomorphic
operations, τ = α·L_m + L_β + (terms in the m_v and constants), with public coefficients of its
choosing. If the image is wrong (δ_r = S'_r − S_r not all 0), acceptance needs either
α·Σρ_rδ_r to equal a value independent of α — probability ≤ 2/min(p, q) over α when Σρ_rδ_r ≢ 0
mod p and mod q — or Σρ_rδ_r ≡ 0, which for ρ_r uniform on 62 bits (:data:`RHO_BITS`) and any
fixed δ ≠ 0 has probability ≤ 2^-62; or coefficients on the β_v other than Σρ_r·w_{r,v}, which leaves a non-zero
combination of 128-bit pseudo-random values to guess (≤ 2^-128 per guess, as the PRF is secure).
So one frame is accepted wrongly with probability about 2^-62 + 2^-127 + 2/min(p, q) per attempt.
ρ must be unknown to the server when it fixes the image: drawn by the client *after* the image
arrives (a second round: hevr's ray sums stay on the workers as futures, so the aggregate is one
more task) — not derived from a hash of the image, which a server could grind (2^t hashes lower
the bound to 2^(t−62)).

The tag key is derived from the private key (:func:`tag_key_of`): α and k are SHAKE-256 of a
domain string and the primes p, q. So it is exactly as secret as the key, needs no file of its
own (nothing new to keep 0600, to lose or to mix up) and is the same on every machine that holds
the key; deriving it is indistinguishable from drawing it as long as p and q are secret (SHAKE-256
as a random oracle), and α is reduced from bits(n) + 128 bits (statistical distance ≤ 2^-128).

PRF. SHAKE-256 keyed by prefixing k to a length-prefixed domain string (store id, channel,
level, component, block number) gives 2^12 values of 128 bits per block (64 KiB of output), so
any subset of voxels costs the blocks it touches (:func:`betas`).
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass
from typing import Any

import gmpy2
import numpy as np

from ..errors import ParameterError
from ..runtime.recent import Recent

__all__ = [
    "BLOCK",
    "RHO_BITS",
    "aggregate_holds",
    "TAG_SUFFIX",
    "TagKey",
    "betas",
    "coefficients",
    "coefficients_at",
    "data_channel",
    "generate_tag_key",
    "raw_check",
    "raw_tags",
    "tag_channel",
    "tag_ciphertexts",
    "tag_key_of",
    "weighted_beta_sums",
    "weighted_beta_total",
]

TAG_SUFFIX = "_tag"  # the tag channel of channel c is c + TAG_SUFFIX (its own array in the store)

BLOCK = 1 << 12  # β values per PRF block
BETA_BYTES = 16
_KEYS = Recent(4)  # n -> TagKey


@dataclass(frozen=True, repr=False)
class TagKey:
    """The owner's tag key: α ∈ Z_n^* and the 32-byte PRF key (secret: never in a store, a log or a graph)."""

    alpha: int
    prf_key: bytes
    n: int

    def __repr__(self) -> str:
        return f"TagKey(<secret>, {int(self.n).bit_length()}-bit n)"


def generate_tag_key(n: int) -> TagKey:
    """A fresh tag key for the modulus ``n`` (α uniform in Z_n^*, from :mod:`secrets`).

    >>> k = generate_tag_key(3 * 11)
    >>> 0 < k.alpha < 33 and k.alpha % 3 and k.alpha % 11 and len(k.prf_key), repr(k)
    (32, 'TagKey(<secret>, 6-bit n)')
    """
    n = int(n)
    while True:
        alpha = secrets.randbelow(n)
        if alpha and gmpy2.gcd(alpha, n) == 1:
            return TagKey(alpha, secrets.token_bytes(32), n)


def tag_key_of(private_key: Any) -> TagKey:
    """The tag key of a :class:`hevr.PrivateKey`, derived from its primes (module docstring);
    cached per key and process.

    >>> import warnings, hevr
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     pub, priv = hevr.generate_keypair(128)
    >>> k = tag_key_of(priv)
    >>> k == tag_key_of(hevr.PrivateKey(pub, int(priv.p), int(priv.q))), 0 < k.alpha < int(pub.n), repr(k)[:15]
    (True, True, 'TagKey(<secret>')
    """
    n = int(private_key.public_key.n)
    got = _KEYS.find(n)
    if got is not None:
        return got
    p, q = sorted((int(private_key.p), int(private_key.q)))
    width = (n.bit_length() + 7) // 8
    secret = b"".join(
        len(b).to_bytes(4, "little") + b for b in (p.to_bytes(width, "little"), q.to_bytes(width, "little"))
    )
    prf_key = hashlib.shake_256(b"hevr-tag-prf-key-v1" + secret).digest(32)
    for counter in range(1 << 16):  # gcd(α, n) > 1 has probability about 2/sqrt(n): never in practice
        raw = hashlib.shake_256(b"hevr-tag-alpha-v1" + counter.to_bytes(4, "little") + secret).digest(width + 16)
        alpha = int.from_bytes(raw, "little") % n
        if alpha and gmpy2.gcd(alpha, n) == 1:
            break
    return _KEYS.keep(n, TagKey(alpha, prf_key, n))


def tag_channel(channel: str) -> str:
    """The tag channel of a stored channel.

    >>> tag_channel("vector"), data_channel("vector_tag"), data_channel("scalar")
    ('vector_tag', 'vector', 'scalar')
    """
    return channel + TAG_SUFFIX


def data_channel(channel: str) -> str:
    """The channel a tag channel belongs to (a data channel is its own)."""
    return channel.removesuffix(TAG_SUFFIX)


def _domain(store_id: str, channel: str, level: int, component: int, block: int) -> bytes:
    parts = [
        str(store_id).encode(),
        str(channel).encode(),
        int(level).to_bytes(4, "little"),
        int(component).to_bytes(4, "little"),
        int(block).to_bytes(8, "little"),
    ]
    return b"hevr-tag-beta-v1" + b"".join(len(p).to_bytes(4, "little") + p for p in parts)


def betas(
    key: TagKey, store_id: str, channel: str, level: int, component: int, voxels: Any, cache: dict | None = None
) -> np.ndarray:
    """β of the flat voxel indices ``voxels``: ``(len, 4)`` uint32 limbs, little-endian (128 bits each).
    ``cache`` (a dict the caller keeps, cleared beyond 1024 blocks) keeps the blocks computed, for
    callers that ask brick by brick: neighbouring bricks share blocks.

    >>> k = TagKey(1, bytes(32), 35)
    >>> a = betas(k, "s", "scalar", 0, 0, [0, 5000, 1])
    >>> b = betas(k, "s", "scalar", 0, 0, [1, 0])
    >>> a.shape, bool((a[0] == b[1]).all() and (a[2] == b[0]).all())   # per voxel, whatever the subset
    ((3, 4), True)
    >>> bool((a[0] != betas(k, "t", "scalar", 0, 0, [0])[0]).any())    # another store: other values
    True
    """
    v = np.asarray(voxels, dtype=np.int64).reshape(-1)
    if v.size and v.min() < 0:
        raise ParameterError("voxels: expected non-negative flat indices, got a negative one")
    out = np.empty((v.size, 4), np.uint32)
    blocks = v // BLOCK
    order = np.argsort(blocks, kind="stable")  # each block's voxels: one slice of this order
    starts = np.flatnonzero(np.r_[True, blocks[order][1:] != blocks[order][:-1]]) if v.size else np.zeros(0, int)
    for a, e in zip(starts.tolist(), np.r_[starts[1:], v.size].tolist()):
        b = int(blocks[order[a]])
        words = None if cache is None else cache.get((store_id, channel, level, component, b))
        if words is None:
            stream = hashlib.shake_256(key.prf_key + _domain(store_id, channel, level, component, b)).digest(
                BLOCK * BETA_BYTES
            )
            words = np.frombuffer(stream, "<u4").reshape(BLOCK, 4)
            if cache is not None:
                if len(cache) >= 1024:
                    cache.clear()
                cache[(store_id, channel, level, component, b)] = words
        sel = order[a:e]
        out[sel] = words[v[sel] - b * BLOCK]
    return out


def _ints(limbs: np.ndarray) -> list[int]:
    return [int.from_bytes(r.astype("<u4").tobytes(), "little") for r in limbs]


def raw_tags(key: TagKey, residues: Any, beta_limbs: np.ndarray) -> list[int]:
    """The tag plaintexts α·m + β mod n of residues ``m`` (in [0, n)) and their β (to encrypt as usual)."""
    n, a = key.n, key.alpha
    return [(a * int(m) + b) % n for m, b in zip(residues, _ints(beta_limbs))]


def tag_ciphertexts(
    private_key: Any, store_id: str, channel: str, level: int, mantissas: Any, voxels: Any
) -> list[list]:
    """The tag ciphertexts E(α·m + β) of a brick's mantissas ``(k, V)`` (int64, component-major) at
    the flat voxel indices ``voxels`` ``(V,)`` of ``channel`` at ``level``: ``k`` lists of ``V``
    ciphertexts, encrypted the owner's way (``private_key.owner``, fresh masks).

    >>> import warnings, hevr
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     pub, priv = hevr.generate_keypair(128)
    >>> (t,) = tag_ciphertexts(priv, "ab", "scalar", 0, [[5, -2]], [0, 7])
    >>> k, b = tag_key_of(priv), betas(tag_key_of(priv), "ab", "scalar", 0, 0, [0, 7])
    >>> [int(priv.raw_decrypt(c)) for c in t] == raw_tags(k, [5 % pub.n, -2 % pub.n], b)
    True
    """
    key = tag_key_of(private_key)
    n = key.n
    q = np.asarray(mantissas, dtype=np.int64)
    owner = private_key.owner
    out = []
    for j in range(q.shape[0]):
        plain = raw_tags(key, [int(m) % n for m in q[j].tolist()], betas(key, store_id, channel, level, j, voxels))
        out.append(owner.encrypt_residues(gmpy2.mpz(t) for t in plain))
    return out


def weighted_beta_sums(beta_limbs: np.ndarray, indptr: Any, voxels: Any, weights: Any) -> list[int]:
    """``B_r = Σ_j w_j·β_{v_j}`` over each row ``r`` of a CSR plan (``voxels`` index ``beta_limbs``),
    exactly, with numpy: β in 16-bit pieces times weights below 2^31 stay below 2^47 per pair, so
    a row's sums fit uint64 up to 2^16 pairs.

    >>> bl = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], np.uint32)      # β = 1 and 2^32
    >>> weighted_beta_sums(bl, [0, 2, 3], [0, 1, 1], [3, 2, 5]) == [3 + 2 * 2**32, 5 * 2**32]
    True
    """
    ip = np.asarray(indptr, dtype=np.int64)
    vox = np.asarray(voxels, dtype=np.int64)
    w = np.asarray(weights, dtype=np.int64)
    if w.size and (w.min() < 0 or w.max() >= 1 << 31):
        raise ParameterError("weights: expected integers in [0, 2^31), got others")
    if (np.diff(ip) > 1 << 16).any():
        raise ParameterError("indptr: expected rows of at most 65536 pairs")
    pieces = np.ascontiguousarray(beta_limbs, dtype="<u4").view("<u2").astype(np.uint64)  # (V, 8) 16-bit pieces
    terms = pieces[vox] * w.astype(np.uint64)[:, None]
    rows = ip.size - 1
    sums = np.zeros((rows, pieces.shape[1]), np.uint64)
    nonempty = np.flatnonzero(np.diff(ip) > 0)
    if nonempty.size:
        sums[nonempty] = np.add.reduceat(terms, ip[nonempty], axis=0)
    return [sum(int(s) << (16 * j) for j, s in enumerate(row)) for row in sums.tolist()]


def weighted_beta_total(beta_limbs: np.ndarray, indptr: Any, voxels: Any, weights: Any, rho: Any) -> int:
    """``Σ_r ρ_r·B_r`` with ``B_r = Σ_j w_j·β_{v_j}`` over the rows of a CSR plan, exactly and in numpy:
    per voxel W_v = Σ ρ_r·w over its pairs (ρ in 16-bit pieces, so every per-voxel sum stays exact in
    float64's 53 bits), then Σ_v β_v·W_v as one integer matrix product of 16-bit β pieces with W in
    pieces small enough that no sum overflows 64 bits; a few Python integers at the end.

    >>> bl = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], np.uint32)      # β = 1 and 2^32
    >>> rho = [2**61 + 5, 3]
    >>> want = sum(r * b for r, b in zip(rho, weighted_beta_sums(bl, [0, 2, 3], [0, 1, 1], [3, 2, 5])))
    >>> weighted_beta_total(bl, [0, 2, 3], [0, 1, 1], [3, 2, 5], rho) == want
    True
    >>> big = [2**40 + 7, 3, 2**33]                                  # weights beyond 2^31: split
    >>> want = sum(r * b for r, b in zip(rho, [big[0] + 2 * 2**32 * big[1], 2**32 * big[2]]))
    >>> weighted_beta_total(bl, [0, 2, 3], [0, 1, 1], [big[0], 2 * big[1], big[2]], rho) == want
    True
    """
    ip = np.asarray(indptr, dtype=np.int64)
    vox = np.asarray(voxels, dtype=np.int64)
    w = np.asarray(weights, dtype=np.int64)
    r = np.asarray(rho, dtype=np.uint64)
    if not vox.size:
        return 0
    if w.min() < 0:
        raise ParameterError("weights: expected non-negative integers, got a negative one")
    if w.max() >= 1 << 31:  # linear in w: its low 31 bits, plus the rest shifted (trilinear with many digits)
        low = w & ((1 << 31) - 1)
        return weighted_beta_total(beta_limbs, ip, vox, low, r) + (
            weighted_beta_total(beta_limbs, ip, vox, w >> 31, r) << 31
        )
    row = np.repeat(np.arange(ip.size - 1), np.diff(ip))
    U = beta_limbs.shape[0]
    per_voxel = int(np.bincount(vox, minlength=U).max())
    if (1 << 16) * int(w.max()) * per_voxel >= 1 << 53:  # float64 sums would round: the exact way
        return sum(int(x) * b for x, b in zip(r.tolist(), weighted_beta_sums(beta_limbs, ip, vox, w)))
    pieces = np.ascontiguousarray(beta_limbs, dtype="<u4").view("<u2").astype(np.uint64)  # (U, P) 16-bit
    h = 63 - 16 - max(1, int(U).bit_length())  # bits of a W piece: 16 + h + log2(U) < 64
    cols, shifts = [], []
    for i in range(4):  # ρ's 16-bit pieces
        rp = ((r >> np.uint64(16 * i)) & np.uint64(0xFFFF)).astype(np.float64)
        Wv = np.bincount(vox, weights=rp[row] * w, minlength=U).astype(np.uint64)  # exact: < 2^53
        for c in range(-(-53 // h)):
            cols.append((Wv >> np.uint64(h * c)) & np.uint64((1 << h) - 1))
            shifts.append(16 * i + h * c)
    S = pieces.T @ np.stack(cols, axis=1)  # (P, columns): every entry < 2^64
    return sum(int(S[j, c]) << (16 * j + shifts[c]) for j in range(S.shape[0]) for c in range(S.shape[1]))


def coefficients(seed: bytes, count: int) -> list[int]:
    """``count`` 64-bit aggregation coefficients from ``seed`` — a fresh :func:`secrets.token_bytes`
    the client draws after the image has arrived (module docstring).

    >>> c = coefficients(b"seed", 3)
    >>> len(c), all(0 <= x < 2**64 for x in c), c == coefficients(b"seed", 3), c != coefficients(b"seeD", 3)
    (3, True, True, True)
    """
    raw = hashlib.shake_256(b"hevr-tag-rho-v1" + seed).digest(8 * int(count))
    return np.frombuffer(raw, "<u8").astype(object).tolist() if count else []


RHO_BITS = 62  # aggregation coefficients: below 2^62, so every weight array stays int64-safe


def coefficients_at(seed: bytes, ids: Any) -> np.ndarray:
    """The coefficients ρ of indices ``ids`` (non-negative) in the seed's stream: uint64 below
    2^62, the same for an index whatever else is asked (the server's tile tasks and the client
    each take the ones they need). The stream comes in blocks of 2^12 values (SHAKE-256 of the
    seed and the block number), so a request costs the blocks its indices touch.

    >>> a = coefficients_at(b"s", [5, 0, 5, 10**6])
    >>> bool(a[0] == a[2]), bool((a < 2**62).all()), bool(coefficients_at(b"s", [0])[0] == a[1])
    (True, True, True)
    >>> bool(coefficients_at(b"s", [10**6])[0] == a[3]), bool(coefficients_at(b"t", [5])[0] != a[0])
    (True, True)
    """
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    out = np.zeros(ids.size, np.uint64)
    if not ids.size:
        return out
    if ids.min() < 0:
        raise ParameterError("ids: expected non-negative indices, got a negative one")
    blocks = ids // BLOCK
    for b in np.unique(blocks).tolist():
        stream = hashlib.shake_256(
            b"hevr-tag-rho-v3" + len(seed).to_bytes(4, "little") + seed + int(b).to_bytes(8, "little")
        ).digest(8 * BLOCK)
        sel = blocks == b
        out[sel] = np.frombuffer(stream, "<u8")[ids[sel] - b * BLOCK]
    return out & np.uint64((1 << RHO_BITS) - 1)


def aggregate_holds(private_key: Any, weighted_sum: int, beta_total: int, aggregate: int) -> bool:
    """Whether the decrypted ``aggregate`` is α·Σρ·S + Σρ·B (mod n), given Σρ·S (``weighted_sum``,
    from the values the key holder decrypted) and Σρ·B (``beta_total``, from the public plan and
    the PRF): the last step of every verified render (per-voxel and packed)."""
    key = tag_key_of(private_key)
    n = int(private_key.public_key.n)
    got = int(private_key.raw_decrypt(gmpy2.mpz(aggregate))) % n
    return got == (key.alpha * int(weighted_sum) + int(beta_total)) % n


def raw_check(key: TagKey, sums: list[int], beta_sums: list[int], rho: list[int], aggregate: int) -> bool:
    """Whether the decrypted aggregate equals α·Σρ·S + Σρ·B (mod n) for the decrypted ray sums ``sums``.

    >>> k = TagKey(7, bytes(32), 101)
    >>> raw_check(k, [2, 3], [5, 1], [1, 4], (7 * (2 + 12) + (5 + 4)) % 101)
    True
    >>> raw_check(k, [2, 4], [5, 1], [1, 4], (7 * (2 + 12) + (5 + 4)) % 101)
    False
    """
    if not len(sums) == len(beta_sums) == len(rho):
        raise ParameterError(
            f"sums: expected as many sums, β sums and coefficients, got {len(sums)}, {len(beta_sums)} and {len(rho)}"
        )
    n = key.n
    want = (key.alpha * sum(r * s for r, s in zip(rho, sums)) + sum(r * b for r, b in zip(rho, beta_sums))) % n
    return int(aggregate) % n == want
