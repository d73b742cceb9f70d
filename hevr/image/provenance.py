"""Who vouches for a frame's verification record: one drawn in this process, or a file's with the
key holder's valid stamp (:mod:`hevr.image.stamp`), of a store the owner has not replaced since
(:mod:`hevr.store.known`); what the frame proves and whether it is what the caller expects
(:mod:`hevr.image.proof`: a frame read from another place than it was saved is *moved*); and the
key's policy for a frame without a record (:func:`check_policy`).

One rule for every kind of frame that carries a record and may come from a file:
:meth:`hevr.PackedImage.decrypt`, :meth:`hevr.EncryptedImage.decrypt` and a packed slice's
decryption call :func:`check_provenance` before any ciphertext is touched.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ..errors import FrameMovedWarning, VerificationError
from ..runtime.scheduler import refuse_foreign_cluster
from ..store import known
from .proof import as_expect, check_expect, first_frame, proof_of
from .stamp import check_stamp

if TYPE_CHECKING:
    from .encrypted import EncryptedImage

log = logging.getLogger(__name__)

__all__ = ["check_policy", "check_provenance", "check_require_verified", "for_file", "refuse_untagged"]


def check_require_verified(require_verified: Any) -> bool:
    """Whether ``require_verified`` asks for a verified frame (True, a store id or a
    :class:`hevr.Expect`); False/None do not.

    >>> check_require_verified(False), check_require_verified("0123456789abcdef")
    (False, True)
    """
    return as_expect(require_verified) is not None


def _store_of(img: Any) -> str | None:
    """The store id an image names (public, unproven without a record)."""
    sid = getattr(img, "store_id", None) or (getattr(img, "info", None) or {}).get("store")
    return sid if isinstance(sid, str) else None


def _store_tags(img: Any) -> bool:
    """Whether the image says its store carries tags: in this process, what the render read of the
    store; from a file, a claim anybody could write (what an unverified frame is anyway)."""
    first = first_frame(img)
    meta = getattr(first, "meta", None)
    if meta is not None:
        return bool(meta.tags)
    said = getattr(first, "tags", None)
    if said is None:
        said = (getattr(first, "info", None) or {}).get("tags")
    return said is True


def check_policy(private_key: Any, img: Any, require_verified: Any, unverified: str) -> None:
    """The key's policy (:class:`hevr.PrivateKey` ``require_tags``): an image without a verification
    record decrypts only if the key holder's own record (MAC'd under the key: :mod:`hevr.store.known`)
    holds its store as verifiable — encrypted or verified on this machine, or imported — and the image
    says its store carries tags (a store relabelled with a known id says it has none), or its store
    was accepted without tags (``hevr.trust_store(ev, key, untagged=True)``), or the caller asks for
    an unverified image by name (``require_verified=False``). A frame file's own word is not enough:
    so a store without tags never yields an image by default, first contact included, and an
    unverified frame of a known verifiable store (a render with ``verify=False``, or one rendered
    where the key is not) decrypts as "not verified"."""
    if img.verification is not None or require_verified is False or not getattr(private_key, "require_tags", False):
        return
    sid = _store_of(img)
    if sid is not None and (
        known.accepted_untagged(sid, private_key) or (_store_tags(img) and known.known_verifiable(sid, private_key))
    ):
        return
    raise VerificationError(
        f"image: not verified ({unverified}), and this key's policy is that every store of it carries tags "
        f"(require_tags), but the store {sid or '(not named)'} is not one your known stores hold as verifiable: a "
        "store without tags — made with the public key only, or stripped by a server — or one this machine never "
        "verified; render it verified once with the key (or import your known stores: hevr known import), accept a "
        "store without tags explicitly (hevr.trust_store(ev, key, untagged=True); hevr render --trust-store "
        "--untagged), or ask for an unverified image by name (require_verified=False; hevr decrypt --unverified); "
        "no image is returned"
    )


def refuse_untagged(ev: Any, private_key: Any) -> None:
    """Before a render where the process knows the key: refuse (:class:`hevr.VerificationError`,
    nothing rendered) a store without tags under a key whose policy requires them, unless the key
    holder accepted that store explicitly (:func:`check_policy`'s rule, a step earlier)."""
    if private_key is None or not getattr(private_key, "require_tags", False) or ev.meta.tags:
        return
    sid = ev.meta.store_id
    if known.accepted_untagged(sid, private_key):
        return
    raise VerificationError(
        f"{ev.path}: expected a store with tags (this key's policy is that every store of it carries them: "
        f"require_tags), got the store {sid} without tags — made with the public key only, or stripped by a "
        "server; if it is yours, accept it explicitly (hevr.trust_store(ev, key, untagged=True); hevr render "
        "--trust-store --untagged); nothing was rendered"
    )


def check_provenance(private_key: Any, img: Any, require_verified: Any, unverified: str) -> None:
    """Refuse (:class:`hevr.VerificationError`, no image) a frame whose record nobody vouches for,
    or that is not what the caller expects (:mod:`hevr.image.proof`).

    Parameters
    ----------
    private_key : PrivateKey
        The key holder's key (its tag key checks the stamp; its policy, unverified frames).
    img :
        The frame: its ``verification`` (``store_id`` and ``drawn_here`` are read) and, from a file,
        its ``stamp`` (:class:`hevr.image.stamp.Stamp`).
    require_verified : bool, str, Expect or None
        True, the store id that must have been proven, or an :class:`hevr.Expect`: a frame without
        a record is refused, and one read from another place than it was saved unless the caller
        named its store and view. None (the default): the key's policy decides about a frame
        without a record; False: an unverified frame is asked for by name.
    unverified : str
        Why a frame may carry no record, for the message (the frame kind's own reasons).
    """
    refuse_foreign_cluster(doing="decrypting")  # the key beside another party's Dask client: refused first
    expect = as_expect(require_verified)
    v = img.verification
    if v is None:
        if expect is not None:
            raise VerificationError(
                f"image: not verified (it carries no check against a store's tags: {unverified}), "
                "and require_verified was given; no image is returned"
            )
        check_policy(private_key, img, require_verified, unverified)
        return
    stamp = getattr(img, "stamp", None)
    if not v.drawn_here and (stamp is None or not check_stamp(private_key, stamp.message, stamp.stamp)):
        what = "carries no stamp" if stamp is None else "carries a stamp that does not match its bytes"
        raise VerificationError(
            f"image: its verification record {what} of the key holder (a verified frame is saved with the key: "
            "img.save(path, private_key=...), hevr render --key): the record or the frame was written by someone "
            "else, or altered; no image is returned"
        )
    replaced = None if v.drawn_here else known.retired_by(v.store_id)  # a file's: an old frame replayed?
    if replaced:
        raise VerificationError(
            f"image: a frame of the store {v.store_id}, which the owner replaced with the store {replaced[1]} at "
            f"{replaced[0]} (the key holder's known stores): an old frame replayed?; no image is returned"
        )
    proof = proof_of(img)  # not None: img carries a verification record
    if expect is not None:
        if proof is None:  # (never skip the caller's check)
            raise VerificationError("image: expected a verified frame with its record, got none; no image is returned")
        check_expect(proof, expect)
    elif proof is not None and proof.moved:
        warnings.warn(
            f"image: not verified for {proof.read_as}: the key holder saved this frame as "
            f"{proof.saved_as}; it is {proof.what} (require_verified with "
            "hevr.Expect(store=..., view=...) checks that it is the frame you expect)",
            FrameMovedWarning,
            stacklevel=4,
        )


def for_file(img: EncryptedImage, private_key: Any, check_with_key: Callable[[Any], object]) -> EncryptedImage:
    """The frame as a file holds it: a verified one checked now with the key (``check_with_key``:
    the frame's decryption, its record required) before it is stamped, or, drawn in this
    process and saved without the key, without its record (a warning: only the key holder's stamp
    makes a record in a file trustworthy); a record read from a stamped file keeps its stamp. The
    check accepts a frame read from another place (``Expect(moved=True)``): saving it again with
    the key is how a frame moved on purpose is stamped for its new place."""
    if img.verification is None:
        return img
    if private_key is not None:
        check_with_key(private_key)  # the key holder checks it before stamping
        return img
    if img.verification.drawn_here:
        log.warning(
            "saving a verified frame without private_key: its verification record is left out (only the "
            "key holder's stamp makes a record in a file trustworthy); pass private_key= to keep it"
        )
        return dataclasses.replace(img, verification=None, stamp=None)
    return img
