"""``hevr known``: the key holder's known stores (:mod:`hevr.store.known`) on the command line.

``hevr known list [--key K]`` prints what is recorded (with the key, every entry of that key is
MAC-checked first: an edited or forged entry exits 1); ``hevr known export FILE --key K`` writes
the key's entries to FILE (0600; ``--force`` replaces FILE) and ``hevr known import FILE --key K``
merges such a file into this machine's (every entry MAC-checked; exit 1 for a forged one), so that
a store the owner re-encrypted on one machine is refused in its old version on the other too.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..store.known import export_known_stores, import_known_stores, known_stores_path
from ..store.known_file import load, verify_entries
from .keys import read_key
from .options import add_general_options
from .parser import wrap
from .util import UsageError

__all__ = ["cmd_known", "known_arguments"]

_KEY_HELP = "the private key (KEY.json) whose entries are MAC'd, checked and carried"


def known_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr known``: its description, examples and sub-commands."""
    p.description = wrap(
        "The key holder's known stores (like SSH's known_hosts): per store name, the store id, "
        "the digest of its owner-bound metadata, whether it is verifiable and the ids the owner "
        "retired (re-encrypted). Renders refuse another store under a known name. Entries are "
        "MAC'd under the private key, so they can be exported on one machine and imported on "
        "another. The file: $HEVR_KNOWN_STORES, else ~/.config/hevr/known_stores.json."
    )
    p.epilog = (
        "examples:\n  hevr known list\n  hevr known list --key key.json      # and check every entry's MAC\n"
        "  hevr known export laptop.json --key key.json\n  hevr known import laptop.json --key key.json\n"
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True, parser_class=type(p))
    ls = sub.add_parser("list", help="print the recorded stores", formatter_class=p.formatter_class)
    ls.add_argument("--key", metavar="KEY.json", help=_KEY_HELP + " (optional here)")
    add_general_options(ls, dask=False)
    ex = sub.add_parser("export", help="write the key's entries to FILE", formatter_class=p.formatter_class)
    ex.add_argument("file", metavar="FILE")
    ex.add_argument("--key", metavar="KEY.json", required=True, help=_KEY_HELP)
    ex.add_argument("--force", action="store_true", help="replace FILE if it exists")
    add_general_options(ex, dask=False)
    im = sub.add_parser(
        "import", help="merge an exported FILE into this machine's known stores", formatter_class=p.formatter_class
    )
    im.add_argument("file", metavar="FILE")
    im.add_argument("--key", metavar="KEY.json", required=True, help=_KEY_HELP)
    add_general_options(im, dask=False)


def _list(args: Any) -> int:
    key = read_key(args.key, private=True) if args.key else None
    kf = load()
    if key is not None:
        verify_entries(kf, key)  # a forged entry: VerificationError, exit 1
    rows = {**kf.unsigned, **kf.signed}
    print(f"known stores in {kf.path}: {len(rows)} {'entry' if len(rows) == 1 else 'entries'}")
    fp = key.public_key.fingerprint if key is not None else None
    for name, e in sorted(rows.items()):
        mac = (
            "unsigned (version 1: used only to refuse)"
            if not e.signed
            else "MAC ok"
            if e.fingerprint == fp
            else "MAC'd (another key)"
            if fp
            else "MAC'd (not checked: no --key)"
        )
        kind = "verifiable" if e.verifiable else "accepted without tags" if e.accepted_untagged else "without tags"
        retired = f", {len(e.retired)} retired" if e.retired else ""
        print(
            f"{name}\n  store {e.store_id}, {kind}, key {e.fingerprint[:16]}…, recorded {e.recorded or '?'}"
            f"{retired}, {mac}"
        )
    return 0


def cmd_known(args: Any) -> int:
    """Run ``hevr known ACTION`` (module docstring)."""
    if args.action == "list":
        return _list(args)
    key = read_key(args.key, private=True)
    path = Path(args.file).expanduser()
    if args.action == "export":
        if path.is_dir():
            raise UsageError(f"FILE: expected a file name, got a folder ({path})")
        n = export_known_stores(path, key, overwrite=args.force)
        print(
            f"exported {n} {'entry' if n == 1 else 'entries'} of the key {key.public_key.fingerprint[:16]}… "
            f"from {known_stores_path()} to {path}"
        )
        return 0
    n = import_known_stores(path, key)
    print(f"imported {path}: {n} {'name' if n == 1 else 'names'} added or changed in {known_stores_path()}")
    return 0
