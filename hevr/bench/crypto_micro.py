"""Paillier primitives at one key size: hevr vs python-paillier (phe) vs a bare gmpy2
modular multiplication, all measured in the same process and run (ratios survive noise)."""

from __future__ import annotations

import secrets
import time
import warnings

from ..crypto.keys import generate_keypair
from ..errors import InsecureKeyWarning


def per_op(fn, args, repeat=3):
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        for a in args:
            fn(*a)
        best = min(best, (time.perf_counter() - t) / len(args))
    return best


def crypto_micro(bits: int, n: int = 200) -> dict:
    """Seconds per operation: ``{"table_s", "rows": [{name, hevr_s, phe_s, bare_s}]}``."""
    import phe

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        pub, priv = generate_keypair(bits)
    t = time.perf_counter()
    _ = priv.owner  # build the fixed-base tables once (reported separately)
    table_s = time.perf_counter() - t
    ppub = phe.PaillierPublicKey(int(pub.n))
    ppriv = phe.PaillierPrivateKey(ppub, int(priv.p), int(priv.q))
    n2 = pub.nsquare
    ms = [secrets.randbelow(2**32) for _ in range(n)]
    cts = priv.encrypt_array(ms)
    pcts = [phe.EncryptedNumber(ppub, int(c)) for c in cts]
    k10 = [secrets.randbelow(2**10) for _ in range(n)]
    k64 = [secrets.randbelow(2**64) for _ in range(n)]
    bare = per_op(lambda a, b: a * b % n2, list(zip(cts, reversed(cts))))
    few = max(20, n // 10)
    rows = [
        (
            "encrypt (public key)",
            per_op(pub.encrypt, [(m,) for m in ms[:few]]),
            per_op(ppub.raw_encrypt, [(m,) for m in ms[:few]]),
        ),
        (
            "encrypt (owner, PrivateKey)",
            per_op(priv.encrypt, [(m,) for m in ms]),
            per_op(ppub.raw_encrypt, [(m,) for m in ms[:few]]),
        ),
        ("decrypt", per_op(priv.decrypt, [(c,) for c in cts]), per_op(ppriv.raw_decrypt, [(int(c),) for c in cts])),
        (
            "⊕ add",
            per_op(pub.add, list(zip(cts, reversed(cts)))),
            per_op(lambda a, b: a._raw_add(a.ciphertext(False), b.ciphertext(False)), list(zip(pcts, reversed(pcts)))),
        ),
        (
            "⊗ 10-bit int",
            per_op(pub.mul, list(zip(cts, k10))),
            per_op(lambda a, k: a._raw_mul(k), list(zip(pcts, k10))),
        ),
        (
            "⊗ 64-bit int",
            per_op(pub.mul, list(zip(cts, k64))),
            per_op(lambda a, k: a._raw_mul(k), list(zip(pcts, k64))),
        ),
    ]
    return {
        "bits": bits,
        "table_s": table_s,
        "rows": [{"name": name, "hevr_s": h, "phe_s": p, "bare_s": bare} for name, h, p in rows],
    }
