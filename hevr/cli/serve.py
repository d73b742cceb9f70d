"""``hevr serve``: the render service beside the cluster (:mod:`hevr.serve`).

Run where the stores and the Dask cluster are; it prints each store's name, id and the URL, and the
key holder connects with ``hevr render --server URL NAME`` (or the store id) or ``hevr.connect(URL)``.
A store is served under the name ``NAME=PATH`` gives it, else its folder's name without ``.zarr``.
It never needs or accepts a private key.

It logs one line per request to stderr (``--no-request-log``: warnings and errors only; the format:
:mod:`hevr.serve.routes.base`, ``docs/operator/tokens.md`` and ``logs.md``), re-reads ``--tokens FILE`` when it changes
or on ``SIGHUP``, and ``--new-token NAME --tokens FILE`` adds a token to the file itself.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import signal
import sys
import time
from collections.abc import Iterator
from typing import Any

import dask

from ..errors import ParameterError
from ..serve.budget import MAX_PIXELS_KEY, MAX_PRODUCTS_CAP, MAX_PRODUCTS_KEY, MAX_TOKEN_PRODUCTS_KEY, parse_count
from ..serve.run import check_listen, open_stores, serve
from ..serve.token_file import TokenFile, add_token
from ..serve.tokens import DEFAULT_CONCURRENT, TokenTable, hash_token, new_token
from . import storage as st
from .cluster import dask_client, describe_client
from .options import add_general_options, add_storage_option, int_range
from .parser import wrap
from .util import UsageError

__all__ = ["cmd_serve", "serve_arguments"]

port_type = int_range(0, 65535, "a TCP port (0: any free one)")
concurrent_type = int_range(1, 256, "1 to 256 renders at once")


def products_type(text: str) -> int:
    """``--max-products``, ``--max-token-products``: a count in [1, 2^62], as an integer or in
    scientific notation (``8e9``; :func:`hevr.serve.budget.parse_count`)."""
    try:
        return parse_count("products", text, MAX_PRODUCTS_CAP)
    except ParameterError:
        raise argparse.ArgumentTypeError(
            f"expected a whole number of products in [1, 2^62] (e.g. 8e9), got {text!r}"
        ) from None


pixels_type = int_range(1, 1 << 26, "a number of pixels in [1, 2^26] (e.g. 1048576 = 1024x1024)")


def budget_config(args: Any) -> dict:
    """The Dask config of the budget options given (:mod:`hevr.serve.budget`; absent: its defaults)."""
    given = {
        MAX_PRODUCTS_KEY: args.max_products,
        MAX_TOKEN_PRODUCTS_KEY: args.max_token_products,
        MAX_PIXELS_KEY: args.max_pixels,
    }
    return {k: v for k, v in given.items() if v is not None}


def serve_arguments(p: argparse.ArgumentParser) -> None:
    """``hevr serve``: its description, examples and arguments."""
    add_general_options(p, dask=True, workers_default="Dask's default threaded scheduler in this process")
    add_storage_option(p)
    p.description = wrap(
        "Serve encrypted stores to key holders over HTTP(S): renders, slices, streamed frames and "
        "the verification round run on the Dask cluster; answers are data only (.hevr images, "
        "length-prefixed units, JSON). Read-only, and no private key is ever needed or accepted. "
        "Each store is served under a name (NAME=PATH, or its folder's name without .zarr) and "
        "its id; "
        "the key holder connects with hevr.connect(URL).open(NAME) or 'hevr render --server URL "
        "NAME --key KEY.json' (verified with the key holder's key)."
    )
    p.epilog = (
        "examples:\n"
        "  hevr serve vol.zarr --workers 2                      # http://127.0.0.1:8750, this machine only\n"
        "  hevr serve ct=scans/2024-ct.zarr mr=scans/mr.zarr    # served as 'ct' and 'mr'\n"
        "  hevr serve a.zarr s3://bucket/b.zarr --scheduler tcp://10.0.0.5:8786 --host 0.0.0.0 \\\n"
        "      --tokens tokens.json --tls-cert cert.pem --tls-key key.pem\n"
        "  hevr serve --new-token radiology --tokens tokens.json  # a token; its entry added to the file\n"
        "  kill -HUP PID                               # hevr serve's PID: read --tokens now, not in 1 s\n"
    )
    p.add_argument(
        "stores",
        metavar="STORE",
        nargs="*",
        help="encrypted volume stores (paths or URLs; NAME=PATH serves one under NAME, else under its "
        "folder's name without .zarr; names unique, of letters, digits and _.@-, not 16 hex digits)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=port_type, default=8750, help="TCP port (default 8750; 0: any free port)")
    p.add_argument("--tokens", metavar="FILE", help="bearer tokens per store (JSON; hevr serve --new-token NAME)")
    p.add_argument("--tls-cert", metavar="CERT", help="TLS certificate chain (PEM); with --tls-key: HTTPS")
    p.add_argument("--tls-key", metavar="KEY", help="TLS private key of the certificate (PEM; not a Paillier key)")
    p.add_argument("--persist", action="store_true", help="keep the stores' bricks in the workers' memory")
    p.add_argument("--backend", choices=("auto", "cpu", "cuda-host", "cuda"), help="arithmetic backend (default auto)")
    p.add_argument(
        "--max-concurrent",
        type=concurrent_type,
        default=4,
        metavar="N",
        help="renders at once on this server (default 4; per token: its 'concurrent')",
    )
    p.add_argument(
        "--max-products",
        type=products_type,
        metavar="N",
        help="modular products one render may cost, estimated before any work (default 2^33 = 8.6e9: a "
        "512x512 trilinear frame of a 512x512x300 CT's 4 vector components passes)",
    )
    p.add_argument(
        "--max-token-products",
        type=products_type,
        metavar="N",
        help="products of one token's renders in flight (default twice --max-products; the server's: "
        "--max-concurrent times --max-products)",
    )
    p.add_argument(
        "--max-pixels", type=pixels_type, metavar="N", help="pixels of one rendered image (default 1048576 = 1024x1024)"
    )
    p.add_argument(
        "--new-token",
        metavar="NAME",
        help="make a fresh token named NAME, add its entry to --tokens FILE (created if missing; mode "
        "0600; the other entries kept as they are; a running server reads it within a second), "
        "print the token once and exit (without --tokens: print the entry to add by hand)",
    )
    p.add_argument(
        "--stores",
        dest="token_stores",
        nargs="+",
        metavar="ID",
        default=None,
        help="with --new-token: the store ids the token may render (default '*': every served store)",
    )
    p.add_argument(
        "--no-request-log",
        dest="request_log",
        action="store_false",
        help="log warnings and errors only (default: also one line per request, on stderr)",
    )


def _new_token(args: Any) -> int:
    """``--new-token NAME``: the token printed once (never logged); its entry added to ``--tokens
    FILE`` (:func:`hevr.serve.token_file.add_token`), or printed to add by hand."""
    if args.stores:
        raise UsageError(
            f"STORE: expected none with --new-token, got {args.stores[0]!r} (--stores ID ... names the "
            "store ids the token may render)"
        )
    stores = args.token_stores or ["*"]
    if args.tokens:
        token, entry = add_token(args.tokens, args.new_token, stores)
        print(f"token:  {token}")
        print(
            "give it to the key holder over a channel you trust (hevr.connect(URL, token=...) or HEVR_TOKEN=... "
            "hevr render --server ...); it is not shown again."
        )
        print(
            f"added {entry['name']!r} (stores: {', '.join(entry['stores'])}) to {args.tokens}; a running "
            "hevr serve --tokens on that file takes it within a second"
        )
        return 0
    token = new_token()
    entry = {"name": args.new_token, "sha256": hash_token(token), "stores": stores, "concurrent": DEFAULT_CONCURRENT}
    TokenTable.from_dict({"version": 1, "tokens": [entry]}, "--new-token")  # the name and stores are checked here
    print(f"token:  {token}")
    print("give it to the key holder (hevr.connect(URL, token=...) or HEVR_TOKEN=... hevr render --server ...);")
    print(
        "add this entry to the tokens file's \"tokens\" list (it holds the token's SHA-256 only), or run "
        "hevr serve --new-token NAME --tokens FILE to have it added:"
    )
    print(json.dumps(entry))
    return 0


@contextlib.contextmanager
def server_log(requests: bool) -> Iterator[None]:
    """The server's log on stderr, each line stamped with the UTC time: the request lines
    (``requests``) and the warnings and errors of ``hevr.serve``."""
    logger = logging.getLogger("hevr.serve")
    handler = logging.StreamHandler(sys.stderr)
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(message)s", "%Y-%m-%dT%H:%M:%SZ")
    fmt.converter = time.gmtime
    handler.setFormatter(fmt)
    saved = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(logging.INFO if requests else logging.WARNING)
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


@contextlib.contextmanager
def reread_on_hangup(tokens: Any) -> Iterator[None]:
    """``SIGHUP`` reads the tokens file again (at the next request) while the block runs."""
    if tokens is None or not hasattr(signal, "SIGHUP"):
        yield
        return
    previous = signal.signal(signal.SIGHUP, lambda signum, frame: tokens.reread())
    try:
        yield
    finally:
        signal.signal(signal.SIGHUP, previous)


def cmd_serve(args: Any) -> int:
    if args.new_token is not None:
        return _new_token(args)
    if args.token_stores is not None:
        raise UsageError(
            "--stores: expected --new-token NAME with it (the tokens file says which stores a token may render)"
        )
    if not args.stores:
        raise UsageError("STORE: expected at least one store to serve, got none")
    if args.scheduler and args.workers:
        raise UsageError("--scheduler/--workers: expected one of them, got both")
    check_listen(args.host, args.port, args.tls_cert, args.tls_key)  # TLS files, host, port: before a cluster starts
    tokens = TokenFile(args.tokens) if args.tokens else None  # re-read when it changes (and on SIGHUP)
    stores = open_stores(args.stores, st.storage_options(args))
    if tokens is None and args.host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"warning: serving on {args.host} without --tokens: anyone who reaches the port can render", file=sys.stderr
        )
    if args.tls_cert is None and args.host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"warning: serving on {args.host} without TLS: tokens and ciphertexts travel in the clear", file=sys.stderr
        )
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
            with server_log(args.request_log), reread_on_hangup(tokens), dask.config.set(budget_config(args)):
                serve(
                    stores,
                    host=args.host,
                    port=args.port,
                    client=client,
                    tokens=tokens,
                    tls_cert=args.tls_cert,
                    tls_key=args.tls_key,
                    max_concurrent=args.max_concurrent,
                    backend=args.backend,
                    on_ready=ready,
                )
        except KeyboardInterrupt:
            pass
    return 0
