"""The owner's store commands: ``hevr encrypt`` (a scan into an encrypted Zarr store) and
``hevr upgrade-store`` (an older store rewritten in the current format).

Each ``cmd_*`` takes the parsed argparse namespace, prints its report on stdout and returns the
exit code; errors are raised and turned into one line and an exit status by
:func:`hevr.cli.main.main` (:mod:`hevr.cli.exits`). What only the command line can check is checked
first, in its words (``UsageError("--out: …")``), before anything is computed. Every size printed
goes through :func:`~hevr.cli.util.xyz` / :func:`~hevr.cli.util.wh`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..crypto.keys import PrivateKey
from ..runtime.scheduler import declared_own
from ..store.upgrade import upgrade_store
from ..store.writer import encrypt_volume
from . import storage as st
from .cluster import dask_client, describe_client
from .describe import channels
from .keys import key_label, read_key
from .packed import (
    packed_encrypt_lines,
)
from .pyramid import level_rows
from .scan import encrypt_input
from .util import (
    Timer,
    UsageError,
    check_store_path,
    check_writable_dir,
    disk_usage,
    human_bytes,
    plural,
    show_progress,
    xyz,
)


# -- encrypt -------------------------------------------------------------------------------
def cmd_encrypt(args: Any) -> int:

    if args.resume and args.overwrite:
        raise UsageError("--resume, --overwrite: expected one of them, got both (they exclude each other)")
    if args.gradient and not args.vector_dims:
        raise UsageError(
            "--gradient: expected --vector-dims K as well (the gradient channel scales the K-dim density encoding)"
        )
    if args.no_scalar and not args.vector_dims:
        raise UsageError("--no-scalar: expected --vector-dims K as well (a store needs at least one channel)")
    so = st.storage_options(args)
    store = st.encrypt_target(args, so)
    key = read_key(args.key)
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    own = args.own_cluster or (bool(args.scheduler) and args.trust_scheduler)  # --trust-scheduler: its old name
    if private and args.scheduler and not (own or declared_own(args.scheduler)):
        raise UsageError(
            f"--key: {args.key} is a private key and --scheduler is set: the owner-side fast path would send "
            "p and q to the cluster's workers, and Dask lets that cluster run code in this process; encrypt with "
            "the public key (.pub.json), or pass --own-cluster if the cluster is yours"
        )
    scan, value_range = encrypt_input(args)  # prints input, scan and value-range lines
    print(f"key:     {key_label(pub)}")
    print(
        "path:    "
        + (
            "owner-side fast path (private key: p, q speed up encryption; the store still holds only the public key)"
            if private
            else "public-key path ((1 + m·n)·h^s mod n², fixed base and short exponents after "
            "Damgård–Jurik–Nielsen; slower than encrypting with the private key)"
        )
    )
    with dask_client(args.scheduler, args.workers, own=own) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = encrypt_volume(
                scan,
                store,
                key,
                brick=args.brick,
                scalar=not args.no_scalar,
                vector_dims=args.vector_dims,
                value_range=value_range,
                digits=args.digits,
                overwrite=args.overwrite,
                resume=args.resume,
                gradient=args.gradient,
                storage_options=so,
                verifiable=args.verifiable,
                layout=args.layout,
                pack_axis=args.pack_axis,
                levels=args.levels,
                progress=show_progress(args, lines=True),
            )
    records = int(np.prod(ev.packing.array_shape(ev.shape))) if ev.packing is not None else int(np.prod(ev.shape))
    n_ct = records * sum(ev.meta.components(ch) for ch in ev.meta.channel_names)
    chans = channels(ev.meta)
    now = getattr(ev, "written_now", {"bricks": ev.meta.n_bricks, "ciphertexts": n_ct})
    bricks = plural(ev.meta.n_bricks, "brick")
    size = human_bytes(st.size_of(ev.path, so))
    if now["bricks"] == 0:
        print(
            f"{args.out}: already complete ({bricks} of {xyz(ev.brick)}, channels {chans}, {n_ct:,} ciphertexts, "
            f"{size}); nothing was left to encrypt"
        )
    else:
        part = (
            f"; resumed: {plural(now['bricks'], 'brick')} ({now['ciphertexts']:,} ciphertexts) encrypted now"
            if now["bricks"] < ev.meta.n_bricks
            else ""
        )
        print(
            f"wrote {args.out}: {bricks} of {xyz(ev.brick)}, channels {chans}, {n_ct:,} ciphertexts, {size}{part}, "
            f"in {t.seconds:.2f} s ({now['ciphertexts'] / max(t.seconds, 1e-9):,.0f} ciphertexts/s)"
        )
    if ev.packing is not None:
        packed_encrypt_lines(ev, args.out)
    elif not ev.vector_dims:
        print("note: scalar channel only (X-ray); add --vector-dims 4 to allow --mode emphasize/tf")
    for name, text in level_rows(ev.meta):
        print(f"{name}: {text}")
    if ev.meta.tags and ev.packing is None:  # a packed store's: packed_encrypt_lines
        print(
            f"verifiable: store id {ev.meta.store_id}; keep it, and render with --key KEY --verify "
            f"{ev.meta.store_id} to refuse any other store a server might answer with (recorded in your known "
            "stores)"
        )
    return 0


# -- upgrade-store ---------------------------------------------------------------------------
def cmd_upgrade_store(args: Any) -> int:
    check_store_path(Path(args.src).expanduser(), "OLD")
    dst = Path(args.dst).expanduser()
    if dst.exists():
        raise UsageError(f"NEW: {args.dst} already exists; choose a new path for the upgraded store")
    check_writable_dir(dst, "NEW")
    with dask_client(args.scheduler, args.workers, own=getattr(args, "own_cluster", False)) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = upgrade_store(args.src, args.dst, client=client, progress=show_progress(args))
    print(
        f"wrote {args.dst}: format {ev.meta.version}, {plural(ev.meta.n_bricks, 'brick')} with digests, "
        f"{human_bytes(disk_usage(ev.path))}, in {t.seconds:.2f} s; {args.src} is unchanged"
    )
    return 0


__all__ = ["cmd_encrypt", "cmd_upgrade_store"]
