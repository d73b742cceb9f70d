"""The key holder on the command line: ``--key``, ``--verify [STORE_ID]`` / ``--no-verify`` and
``--trust-store`` of ``hevr render`` and ``hevr slice`` (:func:`key_holder`), and the lines that say
what a verified frame proves or why a frame is not verified. Packed frames' lines:
:mod:`hevr.cli.packed`.
"""

from __future__ import annotations

from typing import Any

from ..image.proof import FrameProof, proof_of
from ..image.provenance import refuse_untagged
from ..store.known import known_stores_path, trust_store
from .keys import read_key
from .util import UsageError, warn_line

__all__ = ["key_holder", "recorded_proof", "verified_line", "verify_argument", "warn_unverified"]


def recorded_proof(img: Any) -> FrameProof:
    """What a frame that carries a verification record proves (:func:`hevr.image.proof.proof_of`).

    Raises
    ------
    ValueError
        ``img`` has no verification record (the callers check ``img.verification`` first).
    """
    proof = proof_of(img)
    if proof is None:
        raise ValueError("expected a frame with a verification record, got one without")
    return proof


def verify_argument(args: Any) -> bool | str | None:
    """``render(verify=)`` from ``--key``, ``--verify [STORE_ID]`` / ``--no-verify``: with the private
    ``--key`` (read into ``args.private_key``) None lets the store decide; without it the frame is not
    verified (only the key holder's process may draw the seed), and ``--verify`` is refused."""
    args.private_key = read_key(args.key, private=True) if getattr(args, "key", None) else None
    if args.no_verify:
        return False
    if args.private_key is None:
        if args.verify is not None:
            raise UsageError(
                "--verify: expected --key KEY.json as well: only the key holder's process draws the "
                "verification seed and checks the frame (one that renders without the key, on the "
                "cluster, would know the seed before the frame is fixed)"
            )
        return False
    return args.verify


def warn_unverified(args: Any, ev: Any, img: Any) -> None:
    """After a frame is written: one warning line when it is not verified and --no-verify was not asked."""
    if img.verification is not None or args.no_verify:
        return
    if not ev.meta.tags:
        warn_line(
            "not verified: the store has no tags (encrypt it with --verifiable so that a lying server "
            "is caught; --no-verify silences this)"
        )
    elif args.private_key is None and getattr(ev, "remote", None) is not None:  # hevr render|slice --server
        warn_line(
            "not verified: no --key: pass --key KEY.json, the key holder's private key, to verify the "
            "server's answer (the seed is drawn here after the frame has arrived; --no-verify silences this)"
        )
    elif args.private_key is None:
        warn_line(
            "not verified: no --key (the key holder's process verifies: give it --key, or render through "
            "hevr serve from the key holder's machine; --no-verify silences this)"
        )


def key_holder(args: Any, ev: Any) -> bool | str | None:
    """:func:`verify_argument` for the store ``ev``, whose key ``--key`` must be."""
    verify = verify_argument(args)
    if args.private_key is not None and args.private_key.public_key.fingerprint != ev.meta.fingerprint:
        raise UsageError(
            f"--key: expected the private key of the store (fingerprint {ev.meta.fingerprint[:16]}…), "
            f"got {args.key} (fingerprint {args.private_key.public_key.fingerprint[:16]}…)"
        )
    if args.trust_store:
        if args.private_key is None:
            raise UsageError("--trust-store: expected --key KEY.json as well (the known stores are the key holder's)")
        entry = trust_store(ev, args.private_key, untagged=getattr(args, "untagged", False))
        print(
            f"trusted: {ev.path} is now recorded as the store {entry.store_id} in {known_stores_path()}"
            + (" (accepted without tags)" if entry.accepted_untagged else "")
        )
    elif getattr(args, "untagged", False):
        raise UsageError("--untagged: expected --trust-store as well (it accepts a store without tags explicitly)")
    refuse_untagged(ev, args.private_key)  # the key's policy: a store without tags, before anything is rendered
    return verify


def verified_line(img: Any) -> str | None:
    """What a verified frame proves, for the CLI: its store, view and level (None: not verified)."""
    v = img.verification
    if v is None:
        return None
    view = v.camera
    what = (
        f"plane through ({', '.join(f'{x:g}' for x in view.origin)}) along u ({', '.join(f'{x:g}' for x in view.u)})"
        f" and v ({', '.join(f'{x:g}' for x in view.v)}), {view.width}x{view.height} px"
        if not hasattr(view, "position")
        else f"camera at ({', '.join(f'{x:g}' for x in view.position)}) looking at "
        f"({', '.join(f'{x:g}' for x in view.focal_point)}), {view.width}x{view.height} px"
    )
    return (
        f"verified: the frame is the render of store {v.store_id} (channel {v.channel}, {v.sampling} sampling, "
        f"step {v.step:g}, level {v.level}) and its view, {what} (view key {recorded_proof(img).view_key}); checked "
        "against the store's tags and its owner-authenticated metadata"
    )


def verified_row(img: Any) -> str:
    """``hevr info``'s "verified" row of a frame file: what its record would prove (public facts; the
    stamp is checked with the key at decryption)."""
    if img.verification is None:
        return "no (no check against the store's tags: --require-verified refuses it)"
    if img.stamp is None:
        return f"record of store {img.verification.store_id}, without the key holder's stamp (refused at decryption)"
    p = recorded_proof(img)
    moved = (
        f"; read from {p.read_as}: moved, so not verified for this file unless you name its store and view"
        if p.moved
        else ""
    )
    return (
        f"record of store {p.store_id} ({p.store_version[:19]}…), view key {p.view_key}, rendered "
        f"{p.rendered_at or 'at an unrecorded time'}; with the key holder's stamp, saved as {p.saved_as} (checked "
        f"with the key at decryption){moved}"
    )
