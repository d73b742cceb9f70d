"""``hevr stores --server URL``: the stores a ``hevr serve`` serves to this token.

One line per store: its served name, its id, its size (x×y×z voxels, as every hevr command prints
sizes), per-voxel or packed, verifiable or not, its channels, its pyramid levels and its key's
fingerprint (compare it with your key's: ``hevr info key.json``). ``--json`` prints the list as
JSON, sizes in :attr:`hevr.EncryptedVolume.shape`'s order (z, y, x: NumPy's, what
``server.open(name).shape`` gives). Each description is checked as :meth:`hevr.connect`'s
``open`` checks it. The token comes from ``HEVR_TOKEN``, never the command line; the connection
is :func:`hevr.cli.remote.connect_remote`'s, as ``hevr render --server`` makes it (a refused
setting names its option).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from .options import add_general_options
from .parser import wrap
from .remote import connect_remote
from .render_options import add_server_option
from .util import UsageError

__all__ = ["cmd_stores", "describe", "stores_arguments"]


def stores_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr stores``: its description, examples and arguments."""
    add_general_options(p, dask=False)
    add_server_option(
        p,
        "the hevr serve to ask (http(s)://host:port; required); the token comes from the "
        "environment variable HEVR_TOKEN",
    )
    p.description = wrap(
        "List the stores a render server (hevr serve) serves to your token: name, id, size, "
        "per-voxel or packed, verifiable or not, channels, pyramid levels and the key's "
        "fingerprint. The token comes from the environment variable HEVR_TOKEN."
    )
    p.epilog = (
        "examples:\n"
        "  HEVR_TOKEN=... hevr stores --server https://render.example.org:8750 --cafile ca.pem\n"
        "  hevr stores --server http://127.0.0.1:8750 --json     # for scripts; shape in (z, y, x) order\n"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the list as JSON (shape in (z, y, x) order, as server.open(NAME).shape)",
    )


def describe(meta: Any, sid: str, name: str | None) -> dict:
    """What ``hevr stores`` says of one store (its checked public metadata)."""
    return {
        "name": name,
        "id": sid,
        "shape": list(meta.shape),
        "spacing": list(meta.spacing),
        "packed": meta.packing is not None,
        "verifiable": bool(meta.tags),
        "channels": [c for c in ("scalar", "vector", "gradient") if getattr(meta, c) is not None],
        "levels": len(meta.levels),
        "fingerprint": meta.fingerprint,
    }


def _table(rows: list[dict]) -> list[str]:
    head = ("NAME", "ID", "SIZE x*y*z", "LAYOUT", "VERIFIABLE", "CHANNELS", "LEVELS", "KEY")
    body = [
        (
            r["name"] or "-",
            r["id"],
            "x".join(map(str, r["shape"][::-1])),
            "packed" if r["packed"] else "per-voxel",
            "yes" if r["verifiable"] else "no",
            ",".join(r["channels"]),
            str(r["levels"]),
            r["fingerprint"][:16],
        )
        for r in rows
    ]
    widths = [max(len(row[i]) for row in [head, *body]) for i in range(len(head))]
    return ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in [head, *body]]


def cmd_stores(args: Any) -> int:
    if not args.server:
        raise UsageError("--server: expected the URL of a hevr serve (http(s)://host:port), got none")
    server = connect_remote(args)
    rows = [describe(meta, sid, name) for sid, name, meta in server.described()]
    if args.json:
        print(json.dumps({"server": server.url, "stores": rows}, indent=1))
    elif not rows:
        print(f"no stores: {server.url} serves none to this token")
    else:
        print("\n".join(_table(rows)))
    return 0
