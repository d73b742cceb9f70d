"""``hevr keygen`` and ``hevr convert-key``: key pairs, and key files between hevr and
python-paillier (``pheutil``) formats (:mod:`hevr.crypto.phe_keys`).

Every command that takes ``--key`` reads both formats (:func:`hevr.load_key` detects a
pheutil file); ``convert-key`` writes one key file in the other format, ``keygen --format phe``
writes a new pair in pheutil's.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from ..crypto.keys import SECURE_BITS, PrivateKey, generate_keypair
from ..errors import InsecureKeyWarning
from .util import (
    Timer,
    UsageError,
    check_output_file,
    public_key_path,
    read_key,
    warn_line,
)

__all__ = ["cmd_keygen", "cmd_convert_key", "FORMAT_NAMES"]

FORMAT_NAMES = {"hevr": "hevr's JSON key file", "phe": "python-paillier's (pheutil) JSON key file"}


# -- keygen --------------------------------------------------------------------------------
def cmd_keygen(args: Any) -> int:

    out = Path(args.out).expanduser()
    pub_out = public_key_path(out)
    for p in (out, pub_out):
        check_output_file(p)
        if p.exists() and not args.force:
            what = "" if p == out else " (the public key beside it)"
            raise UsageError(f"--out: {p}{what} exists; pass --force to replace the key pair")
    if args.bits < SECURE_BITS:
        warn_line(f"a {args.bits}-bit key is NOT secure; use --bits {SECURE_BITS} or more for real data")
    with Timer() as t, warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        pub, priv = generate_keypair(args.bits)
    priv.save(out, overwrite=args.force, format=args.format)
    pub.save(pub_out, overwrite=args.force, format=args.format)
    print(f"generated a {args.bits}-bit Paillier key pair in {t.seconds:.2f} s ({FORMAT_NAMES[args.format]})")
    print(f"  private key: {out}  (mode 0600 - keep it secret, it decrypts every image)")
    print(f"  public key:  {pub_out}  (give this one to whoever encrypts)")
    print(f"  fingerprint: {pub.fingerprint}")
    return 0



# -- convert-key ---------------------------------------------------------------------------
def cmd_convert_key(args: Any) -> int:
    src = Path(args.key).expanduser()
    out = Path(args.out).expanduser()
    check_output_file(out)
    if out.exists() and out.resolve() == src.resolve():
        raise UsageError(f"--out: expected another file than KEY, got {args.out} for both")
    if out.exists() and not args.force:
        raise UsageError(f"--out: {out} exists; pass --force to replace it")
    key = read_key(args.key)
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    key.save(out, overwrite=args.force, format=args.format)
    kind = "private" if private else "public"
    mode = " (mode 0600)" if private else ""
    print(f"wrote {out}: the {pub.bits}-bit {kind} key as {FORMAT_NAMES[args.format]}{mode}")
    print(f"  fingerprint: {pub.fingerprint}")
    if pub.bits < SECURE_BITS:
        warn_line(f"a {pub.bits}-bit key is NOT secure; use {SECURE_BITS} bits or more for real data")
    return 0
