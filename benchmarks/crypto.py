"""Paillier primitives: hevr vs python-paillier (phe) vs a bare gmpy2 modular multiplication.

Run: python benchmarks/crypto.py [--bits 1024 2048 3072] [--n 200]
Prints a table and appends it to benchmarks/RESULTS.md. All columns of one key size are
measured in the same run, so the ratios are meaningful on a noisy machine.
"""

from __future__ import annotations

import argparse
import secrets
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gmpy2  # noqa: E402
import phe  # noqa: E402
from _machine import append, machine  # noqa: E402

import hevr  # noqa: E402


def per_op(fn, args, repeat=3):
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        for a in args:
            fn(*a)
        best = min(best, (time.perf_counter() - t) / len(args))
    return best


def bench(bits: int, n: int) -> list[tuple[str, float, float, float]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pub, priv = hevr.generate_keypair(bits)
    t = time.perf_counter()
    priv.owner  # build the fixed-base tables once (reported separately)
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
        ("encrypt (public key)", per_op(pub.encrypt, [(m,) for m in ms[:few]]),
         per_op(ppub.raw_encrypt, [(m,) for m in ms[:few]])),
        ("encrypt (owner, PrivateKey)", per_op(priv.encrypt, [(m,) for m in ms]),
         per_op(ppub.raw_encrypt, [(m,) for m in ms[:few]])),
        ("decrypt", per_op(priv.decrypt, [(c,) for c in cts]), per_op(ppriv.raw_decrypt, [(int(c),) for c in cts])),
        ("⊕ add", per_op(pub.add, list(zip(cts, reversed(cts)))),
         per_op(lambda a, b: a._raw_add(a.ciphertext(False), b.ciphertext(False)), list(zip(pcts, reversed(pcts))))),
        ("⊗ 10-bit int", per_op(pub.mul, list(zip(cts, k10))),
         per_op(lambda a, k: a._raw_mul(k), list(zip(pcts, k10)))),
        ("⊗ 64-bit int", per_op(pub.mul, list(zip(cts, k64))),
         per_op(lambda a, k: a._raw_mul(k), list(zip(pcts, k64)))),
    ]
    return [(name, h, p, bare) for name, h, p in rows], table_s


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bits", type=int, nargs="+", default=[1024, 2048, 3072])
    ap.add_argument("--n", type=int, default=200, help="operations per measurement")
    args = ap.parse_args(argv)
    lines = [f"## crypto.py — Paillier primitives\n\nMachine: {machine()}\n",
             "| bits | operation | hevr µs | phe µs | phe / hevr | bare a·b mod n² µs | hevr / bare |",
             "|---:|---|---:|---:|---:|---:|---:|"]
    for bits in args.bits:
        rows, table_s = bench(bits, args.n)
        for name, h, p, bare in rows:
            lines.append(f"| {bits} | {name} | {h * 1e6:,.1f} | {p * 1e6:,.1f} | {p / h:,.2f}× | {bare * 1e6:,.2f} | {h / bare:,.2f} |")
        lines.append(f"| {bits} | owner tables (once per key and process) | {table_s * 1e6:,.0f} | | | | |")
        print("\n".join(lines[-7:]), flush=True)
    lines.append("\nphe columns: `raw_encrypt` (random r, r^n mod n² with gmpy2), `raw_decrypt` (CRT), "
                 "`_raw_add`, `_raw_mul`. Goals at 2048 bits: owner encrypt ≥ 20× phe; decrypt no slower "
                 "than phe; ⊕ within 1.2× of the bare multiplication.")
    text = "\n".join(lines)
    print(text)
    append(text)


if __name__ == "__main__":
    main()
