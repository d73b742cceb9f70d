"""Public-key and owner encryption rates at 2048 bits: ciphertexts/s, best of 3 runs of N values
(every ciphertext decrypted and checked). ``python benchmarks/public_encrypt.py [N]``; run it
with ``PYTHONPATH`` pointing at an older checkout for a before/after (benchmarks/history.md)."""

import secrets
import sys
import time
import warnings

warnings.simplefilter("ignore")  # before hevr imports: the benchmark's output is its numbers
import hevr  # noqa: E402

N = int(sys.argv[1]) if len(sys.argv) > 1 else 200
pub, priv = hevr.generate_keypair(2048)
vals = [secrets.randbelow(1 << 16) for _ in range(N)]
pub.encrypt_array(vals[:2])
priv.encrypt_array(vals[:2])  # tables built (once per key and process)
for name, key in (("public", pub), ("owner", priv)):
    rates = []
    for _ in range(3):
        t = time.perf_counter()
        cts = key.encrypt_array(vals)
        rates.append(N / (time.perf_counter() - t))
    assert priv.decrypt_array(cts) == vals
    print(f"{name}: {max(rates):.1f} ciphertexts/s (runs {', '.join(f'{r:.1f}' for r in rates)})")
