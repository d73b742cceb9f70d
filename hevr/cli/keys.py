"""Key files on the command line: ``hevr keygen`` and ``hevr convert-key`` (key pairs, and key
files between hevr and python-paillier (``pheutil``) formats, :mod:`hevr.crypto.phe_keys`),
reading a ``--key`` and what ``hevr info KEY`` prints about one.

Every command that takes ``--key`` reads both formats (:func:`hevr.load_key` detects a
pheutil file); ``convert-key`` writes one key file in the other format, ``keygen --format phe``
writes a new pair in pheutil's. Light to import (gmpy2 and numpy through :mod:`hevr.crypto`,
no Dask or Zarr): ``hevr info KEY`` runs from here.
"""

from __future__ import annotations

import json
import stat
import warnings
from pathlib import Path
from typing import Any

from ..crypto.keyfile import load_key
from ..crypto.keys import SECURE_BITS, PrivateKey, generate_keypair
from ..errors import InsecureKeyWarning
from .util import (
    Timer,
    UsageError,
    check_output_file,
    print_rows,
    warn_line,
)

__all__ = ["FORMAT_NAMES", "cmd_convert_key", "cmd_keygen", "info_key", "key_label", "public_key_path", "read_key"]

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
        pub, priv = generate_keypair(args.bits, require_tags=args.require_tags)
    priv.save(out, overwrite=args.force, format=args.format)
    pub.save(pub_out, overwrite=args.force, format=args.format)
    print(f"generated a {args.bits}-bit Paillier key pair in {t.seconds:.2f} s ({FORMAT_NAMES[args.format]})")
    print(f"  private key: {out}  (mode 0600 - keep it secret, it decrypts every image)")
    print(f"  public key:  {pub_out}  (give this one to whoever encrypts)")
    print(f"  fingerprint: {pub.fingerprint}")
    print(f"  policy:      {policy_text(priv, args.format)}")
    return 0


def policy_text(priv: PrivateKey, fmt: str = "hevr") -> str:
    """The key's policy, for a person."""
    if fmt == "phe":
        return (
            "none (a pheutil file cannot hold it; 'hevr convert-key' to hevr's format and 'hevr key-policy "
            "--require-tags' give it one)"
        )
    return (
        "every store of this key carries tags (a store without them is refused; 'hevr key-policy "
        "--no-require-tags' turns it off)"
        if priv.require_tags
        else "stores without tags are accepted with a warning ('hevr key-policy --require-tags' requires tags)"
    )


# -- key-policy ----------------------------------------------------------------------------
def cmd_key_policy(args: Any) -> int:
    key = read_key(args.key, private=True)
    path = Path(args.key).expanduser()
    if args.require_tags is None or args.require_tags == key.require_tags:
        print(f"{path}: {policy_text(key)}")
        return 0
    check_output_file(path)
    try:
        hevr_format = json.loads(path.read_text(encoding="utf-8")).get("format") == "hevr-key"
    except (OSError, ValueError, AttributeError):
        hevr_format = False
    if not hevr_format:
        raise UsageError(
            f"KEY: expected a key file in hevr's format (a pheutil file cannot hold a policy), got {path}; "
            "'hevr convert-key KEY --out key.json --format hevr' first"
        )
    key.with_policy(require_tags=args.require_tags).save(path, overwrite=True)  # asked for: rewritten in place
    print(f"wrote {path}: {policy_text(key.with_policy(require_tags=args.require_tags))}")
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
    if private and args.format == "phe" and key.require_tags:
        print(
            "  policy:      not kept: a pheutil file cannot hold the key's policy (every store carries tags); a key "
            "read back from it has none ('hevr key-policy KEY --require-tags' gives it back)"
        )
    print(f"  fingerprint: {pub.fingerprint}")
    if pub.bits < SECURE_BITS:
        warn_line(f"a {pub.bits}-bit key is NOT secure; use {SECURE_BITS} bits or more for real data")
    return 0


# -- reading a key -------------------------------------------------------------------------
def public_key_path(path: str | Path) -> Path:
    """``key.json`` -> ``key.pub.json``; ``key`` -> ``key.pub``."""
    path = Path(path)
    if path.suffix == ".json":
        return path.with_name(path.stem + ".pub.json")
    return path.with_name(path.name + ".pub")


def read_key(path: str, private: bool = False) -> Any:
    """Load a key file; insecure-size warnings are left to keygen/info (bits are shown there).

    ``private``: refuse a public key (``key: expected a private key file, …``). Errors name
    the ``key``, as :func:`hevr.load_key` does; each command says which argument that is.
    """
    if Path(path).expanduser().is_dir():
        raise UsageError(f"key: expected a key file, got a folder ({path})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        key = load_key(Path(path).expanduser())
    if private and not isinstance(key, PrivateKey):
        raise UsageError(f"key: expected a private key file, got a public key ({path})")
    return key


def key_label(pub: Any) -> str:
    weak = " (NOT secure: < 2048 bits)" if pub.bits < SECURE_BITS else ""
    return f"{pub.bits}-bit{weak}, fingerprint {pub.fingerprint}"


def info_key(path: Path, fmt: str = "hevr") -> int:
    """``hevr info KEY``: kind, format, size and fingerprint of a key file (never its secret)."""
    key = read_key(str(path))
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    rows = [
        ("path", path),
        ("kind", "private key (holds the secret primes; not shown)" if private else "public key"),
        ("format", fmt),
        ("bits", f"{pub.bits}" + (" (NOT secure: < 2048 bits)" if pub.bits < SECURE_BITS else "")),
        ("fingerprint", pub.fingerprint),
    ]
    rows.append(("file mode", f"{stat.S_IMODE(path.stat().st_mode):04o}"))
    print_rows(rows)  # a private key others may read: load_key warned already (KeyFilePermissionWarning)
    return 0
