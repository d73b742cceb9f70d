"""Who vouches for a frame's verification record: one drawn in this process, or a file's with the
key holder's valid stamp (:mod:`hevr.image.stamp`), read under the name it was saved as, of a store
the owner has not replaced since (:mod:`hevr.store.known`).

One rule for every kind of frame that carries a record and may come from a file:
:meth:`hevr.PackedImage.decrypt`, :meth:`hevr.EncryptedImage.decrypt` and a packed slice's
decryption call :func:`check_provenance` before any ciphertext is touched.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

from ..errors import ParameterError, VerificationError
from ..store.known import retired_by
from .stamp import check_stamp

log = logging.getLogger(__name__)

__all__ = ["check_provenance", "check_require_verified", "for_file"]


def check_require_verified(require_verified: Any) -> bool:
    """Whether ``require_verified`` asks for a verified frame (True or a store id); False/None do not.

    >>> check_require_verified(False), check_require_verified("0123456789abcdef")
    (False, True)
    """
    if require_verified is False or require_verified is None:
        return False
    if not (require_verified is True or isinstance(require_verified, str)):
        raise ParameterError(f"require_verified: expected True, False or a store id, got {require_verified!r}")
    return True


def check_provenance(private_key: Any, verification: Any, stamp: Any, require_verified: Any,
                     unverified: str) -> None:
    """Refuse (:class:`hevr.VerificationError`, no image) a frame whose record nobody vouches for.

    Parameters
    ----------
    private_key : PrivateKey
        The key holder's key (its tag key checks the stamp).
    verification :
        The frame's record (``store_id`` and ``drawn_here`` are read), or None.
    stamp : tuple or None
        ``(stamp, message, saved_as, read_as)`` of a file that carried one (``read_as`` may be
        missing or None: bytes not read from a named file).
    require_verified : bool or str
        True, or the store id that must have been proven: a frame without a record is refused.
    unverified : str
        Why a frame may carry no record, for the message (the frame kind's own reasons).
    """
    v = verification
    if check_require_verified(require_verified):
        if v is None:
            raise VerificationError(f"image: not verified (it carries no check against a store's tags: {unverified}), "
                                    "and require_verified was given; no image is returned")
        if isinstance(require_verified, str) and v.store_id != require_verified:
            raise VerificationError(f"image: expected a frame of the store {require_verified}, got one of the store "
                                    f"{v.store_id}; no image is returned")
    if v is None or v.drawn_here:
        return
    if stamp is None or not check_stamp(private_key, stamp[1], stamp[0]):
        what = "carries no stamp" if stamp is None else "carries a stamp that does not match its bytes"
        raise VerificationError(
            f"image: its verification record {what} of the key holder (a verified frame is saved with the key: "
            "img.save(path, private_key=...), hevr render --key): the record or the frame was written by someone "
            "else, or altered; no image is returned")
    saved, read = stamp[2], stamp[3] if len(stamp) > 3 else None
    if read is not None and saved != read:
        raise VerificationError(
            f"image: the key holder saved this verified frame as {saved!r}, and it was read as {read!r}: another "
            "frame put in this one's place? (if you renamed it yourself, give it its name back); no image is "
            "returned")
    replaced = retired_by(v.store_id)
    if replaced:
        raise VerificationError(
            f"image: a frame of the store {v.store_id}, which the owner replaced with the store {replaced[1]} at "
            f"{replaced[0]} (the key holder's known stores): an old frame replayed?; no image is returned")


def for_file(img: Any, private_key: Any, check_with_key: Any) -> Any:
    """The frame as a file holds it: a verified one checked now with the key (``check_with_key``:
    the frame's decryption with ``require_verified=True``) before it is stamped, or, drawn in this
    process and saved without the key, without its record (a warning: only the key holder's stamp
    makes a record in a file trustworthy); a record read from a stamped file keeps its stamp."""
    if img.verification is None:
        return img
    if private_key is not None:
        check_with_key(private_key)  # the key holder checks it before stamping
        return img
    if img.verification.drawn_here:
        log.warning("saving a verified frame without private_key: its verification record is left out (only the "
                    "key holder's stamp makes a record in a file trustworthy); pass private_key= to keep it")
        return dataclasses.replace(img, verification=None, stamp=None)
    return img
