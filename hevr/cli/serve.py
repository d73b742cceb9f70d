"""``hevr serve``: the render service beside the cluster (:mod:`hevr.serve`).

Run where the stores and the Dask cluster are; it prints each store's name, id and the URL, and the
key holder connects with ``hevr render --server URL NAME`` (or the store id) or ``hevr.connect(URL)``.
A store is served under the name ``NAME=PATH`` gives it, else its folder's name without ``.zarr``.
It never needs or accepts a private key.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ..errors import ParameterError
from ..serve.run import open_stores, serve
from ..serve.tokens import TokenTable, hash_token, new_token
from . import storage as st
from .cluster import dask_client, describe_client
from .options import add_general_options, add_storage_option, int_range
from .parser import wrap
from .util import UsageError

__all__ = ["cmd_serve", "serve_arguments"]

port_type = int_range(0, 65535, "a TCP port (0: any free one)")
concurrent_type = int_range(1, 256, "1 to 256 renders at once")


def serve_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr serve``: its description, examples and arguments."""
    add_general_options(p, dask=True, workers_default="Dask's default threaded scheduler in this process")
    add_storage_option(p)
    p.description = wrap("Serve encrypted stores to key holders over HTTP(S): renders, slices, streamed frames and "
                         "the verification round run on the Dask cluster; answers are data only (.hevr images, "
                         "length-prefixed units, JSON). Read-only, and no private key is ever needed or accepted. "
                         "Each store is served under a name (NAME=PATH, or its folder's name without .zarr) and "
                         "its id; "
                         "the key holder connects with hevr.connect(URL).open(NAME) or 'hevr render --server URL "
                         "NAME --key KEY.json' (verified with the key holder's key).")
    p.epilog = ("examples:\n"
                "  hevr serve vol.zarr --workers 2                      # http://127.0.0.1:8750, this machine only\n"
                "  hevr serve ct=scans/2024-ct.zarr mr=scans/mr.zarr    # served as 'ct' and 'mr'\n"
                "  hevr serve a.zarr s3://bucket/b.zarr --scheduler tcp://10.0.0.5:8786 --host 0.0.0.0 \\\n"
                "      --tokens tokens.json --tls-cert cert.pem --tls-key key.pem\n"
                "  hevr serve --new-token radiology                     # a token and its tokens-file entry\n")
    p.add_argument("stores", metavar="STORE", nargs="*",
                   help="encrypted volume stores (paths or URLs; NAME=PATH serves one under NAME, else under its "
                        "folder's name without .zarr; names unique, of letters, digits and _.@-, not 16 hex digits)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=port_type, default=8750, help="TCP port (default 8750; 0: any free port)")
    p.add_argument("--tokens", metavar="FILE", help="bearer tokens per store (JSON; hevr serve --new-token NAME)")
    p.add_argument("--tls-cert", metavar="CERT", help="TLS certificate chain (PEM); with --tls-key: HTTPS")
    p.add_argument("--tls-key", metavar="KEY", help="TLS private key of the certificate (PEM; not a Paillier key)")
    p.add_argument("--persist", action="store_true", help="keep the stores' bricks in the workers' memory")
    p.add_argument("--backend", choices=("auto", "cpu", "cuda-host", "cuda"), help="arithmetic backend (default auto)")
    p.add_argument("--max-concurrent", type=concurrent_type, default=4, metavar="N",
                   help="renders at once on this server (default 4; per token: its 'concurrent')")
    p.add_argument("--new-token", metavar="NAME", help="print a fresh token and its tokens-file entry, then exit")


def cmd_serve(args: Any) -> int:
    if args.new_token is not None:
        token = new_token()
        entry = {"name": args.new_token, "sha256": hash_token(token), "stores": ["*"], "concurrent": 2}
        TokenTable.from_dict({"version": 1, "tokens": [entry]}, "--new-token")  # the name is checked here
        print(f"token:  {token}")
        print("give it to the key holder (hevr.connect(URL, token=...) or HEVR_TOKEN=... hevr render --server ...);")
        print("add this entry to the tokens file's \"tokens\" list (it holds the token's SHA-256 only); narrow "
              "\"stores\" to their ids:")
        print(json.dumps(entry))
        return 0
    if not args.stores:
        raise UsageError("STORE: expected at least one store to serve, got none")
    if args.scheduler and args.workers:
        raise UsageError("--scheduler/--workers: expected one of them, got both")
    if (args.tls_cert is None) != (args.tls_key is None):
        raise UsageError("--tls-cert/--tls-key: expected both or neither, got one")
    tokens = TokenTable.load(args.tokens) if args.tokens else None
    stores = open_stores(args.stores, st.storage_options(args))
    if tokens is None and args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: serving on {args.host} without --tokens: anyone who reaches the port can render",
              file=sys.stderr)
    if args.tls_cert is None and args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: serving on {args.host} without TLS: tokens and ciphertexts travel in the clear",
              file=sys.stderr)
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        if args.persist:
            if client is None:
                raise ParameterError("--persist: expected --workers N or --scheduler (resident bricks live on workers)")
            stores = {name: ev.persist(client=client, backend=args.backend) for name, ev in stores.items()}
        for name, ev in stores.items():
            tags = ", verifiable" if ev.meta.tags else ""
            size = "x".join(map(str, ev.shape[::-1]))
            print(f"store:   {ev.meta.store_id}  {name}  {ev.path}  ({size} voxels{tags})")

        def ready(url: str) -> None:
            print(f"serving: {url}  (Ctrl-C stops)", flush=True)

        sys.stdout.flush()
        try:
            serve(stores, host=args.host, port=args.port, client=client, tokens=tokens, tls_cert=args.tls_cert,
                  tls_key=args.tls_key, max_concurrent=args.max_concurrent, backend=args.backend, on_ready=ready)
        except KeyboardInterrupt:
            pass
    return 0
