"""What a verified frame proves, and what its reader expects of it (issue 47).

A verified frame (one whose record the key holder checked: drawn in this process, or read from a
file with the key holder's stamp, :mod:`hevr.image.stamp`) proves that its pixels are the render
of one *view* of one *version* of one *store*:

    proof = (store id, store version, view, view key, rendered at, saved as, read as)

- the store version is the digest of the store's owner-bound metadata (``sha256:…``, the one the
  key holder's known stores keep: :mod:`hevr.store.known`);
- the view is what the record's check fixed: the camera or slice plane, the pyramid level, the
  channel and the sampling (per-voxel frames: the step too); its key is the first 16 hex digits of
  the SHA-256 of its canonical JSON, what ``hevr render`` prints and ``--expect-view`` takes;
- ``rendered at`` is when the seed was drawn (UTC), kept under the stamp;
- ``saved as`` is where the key holder saved the file (the stamp binds it), ``read as`` where it
  was read from.

It does not prove that the frame is the one that belongs where it was found: another patient's
stamped frame, or another view of this one, copied over a file is genuine — of *its* store and
view. So a frame read from another place than it was saved is *moved*, and
``require_verified=True`` (or a store id) refuses it; the caller states what it expects instead,
with :class:`Expect` (``--expect-store ID --expect-view KEY`` on the CLI), which a moved frame
may meet. ``Expect(moved=True)`` accepts a frame wherever it was saved (moved on purpose; saving
it again with the key stamps it for its new place, keeping its render time).

>>> Expect(store="0123456789abcdef", max_age=3600).max_age
3600.0
>>> Expect(view="x")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
hevr.errors.ParameterError: view: expected a view key of 16 lower-case hex digits (...), got 'x'
>>> view_key({"camera": {"kind": "plane"}, "level": 0}) == view_key({"level": 0, "camera": {"kind": "plane"}})
True
"""

from __future__ import annotations

import calendar
import math
import re
import time
from dataclasses import dataclass
from typing import Any

from ..crypto.mac import digest
from ..errors import ParameterError, VerificationError
from ..store.authenticity import authenticated_fields, metadata_digest
from .stamp import TIME_FORMAT, rendered_at

__all__ = ["Expect", "FrameProof", "as_expect", "check_expect", "first_frame", "proof_of", "view_key", "view_of"]

_HEX16 = re.compile(r"[0-9a-f]{16}")
CLOCK_SKEW = 300.0  # seconds a stamp's render time may lie ahead of this machine's clock


def view_key(view: dict[str, Any]) -> str:
    """The 16-hex-digit key of a view (module docstring)."""
    return digest(view).hex()[:16]


@dataclass(frozen=True)
class Expect:
    """What the caller expects of a verified frame: ``require_verified=hevr.Expect(...)``.

    Parameters
    ----------
    store : str, optional
        The store id (16 hex digits) the frame must be of.
    view : str, optional
        The view it must show, as its view key (:func:`view_key` of the camera or plane, level,
        channel and sampling: ``hevr.proof_of(img).view_key``; ``hevr render`` prints it,
        ``hevr info FRAME`` shows it).
    max_age : float, optional
        Seconds: a frame rendered longer ago (or whose render time is unknown) is refused.
    moved : bool
        Accept a frame read from another place than the key holder saved it (on purpose).
    """

    store: str | None = None
    view: Any = None
    max_age: float | None = None
    moved: bool = False

    def __post_init__(self) -> None:
        if self.store is not None and not (isinstance(self.store, str) and _HEX16.fullmatch(self.store)):
            raise ParameterError(f"store: expected a store id of 16 lower-case hex digits, got {self.store!r:.40}")
        v = self.view
        if v is not None and not (isinstance(v, str) and _HEX16.fullmatch(v)):
            raise ParameterError(
                f"view: expected a view key of 16 lower-case hex digits (hevr.proof_of(img).view_key; "
                f"a camera alone does not fix sampling, level and channel), got {v!r:.40}"
            )
        if self.max_age is not None:
            if (
                isinstance(self.max_age, bool)
                or not isinstance(self.max_age, (int, float))
                or not (math.isfinite(self.max_age) and self.max_age > 0)
            ):
                raise ParameterError(f"max_age: expected a positive number of seconds, got {self.max_age!r:.40}")
            object.__setattr__(self, "max_age", float(self.max_age))
        if not isinstance(self.moved, bool):
            raise ParameterError(f"moved: expected True or False, got {self.moved!r:.40}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {"store": self.store, "view": self.view, "max_age": self.max_age, "moved": self.moved}


def as_expect(require_verified: Any) -> Expect | None:
    """``require_verified`` as an :class:`Expect` (None: not required): True, a store id or an Expect.

    >>> as_expect(None), as_expect(False), as_expect(True), as_expect("0123456789abcdef").store
    (None, None, Expect(store=None, view=None, max_age=None, moved=False), '0123456789abcdef')
    """
    if require_verified is None or require_verified is False:
        return None
    if require_verified is True:
        return Expect()
    if isinstance(require_verified, Expect):
        return require_verified
    if isinstance(require_verified, str):
        return Expect(store=require_verified)
    raise ParameterError(
        f"require_verified: expected True, False, a store id or a hevr.Expect, got {require_verified!r:.60}"
    )


@dataclass(frozen=True)
class FrameProof:
    """What a verified frame proves (module docstring)."""

    store_id: str
    store_version: str
    view: dict[str, Any]
    view_key: str
    rendered_at: str = ""
    saved_as: str | None = None
    read_as: str | None = None

    @property
    def moved(self) -> bool:
        """Read from another place than the key holder saved it."""
        return self.saved_as is not None and self.read_as is not None and self.saved_as != self.read_as

    @property
    def what(self) -> str:
        """What the frame is, for a person: its store, version, view and render time."""
        when = f", rendered {self.rendered_at}" if self.rendered_at else ""
        return f"a frame of the store {self.store_id} ({self.store_version[:19]}…), view {self.view_key}{when}"

    def describe(self) -> str:
        """One line: what the frame proves, and where it was saved if it was read elsewhere."""
        where = (
            f"; saved by the key holder as {self.saved_as}, read from {self.read_as}: it proves what it shows, "
            "not that it belongs here"
            if self.moved
            else ""
        )
        return self.what + where


def _camera_dict(cam: Any) -> Any:
    return cam.to_dict() if callable(getattr(cam, "to_dict", None)) else cam


def first_frame(img: Any) -> Any:
    """A frame, or the first component frame of a colour frame (which share camera, plan and store)."""
    comps = getattr(img, "components", None)
    return comps[0] if isinstance(comps, list) else img


def view_of(img: Any) -> dict[str, Any]:
    """The view a verified frame shows, from what its check fixed (module docstring)."""
    v = img.verification
    if hasattr(v, "camera"):  # a per-voxel frame's record holds its whole geometry
        return {
            "camera": _camera_dict(v.camera),
            "sampling": v.sampling,
            "step": float(v.step),
            "level": int(v.level),
            "channel": v.channel,
        }
    first = first_frame(img)
    cam = getattr(first, "camera", None) or getattr(first, "plane", None)
    plan = getattr(first, "plan", None)
    return {
        "camera": _camera_dict(cam),
        "sampling": getattr(plan, "sampling", None),
        "level": int(v.level),
        "channel": v.channel,
    }


def proof_of(img: Any) -> FrameProof | None:
    """What ``img`` proves (None: no verification record). Its record's seed is trusted only after
    :func:`hevr.image.provenance.check_provenance`: read this after a decryption, or to show."""
    v = img.verification
    if v is None:
        return None
    stamp = getattr(img, "stamp", None)
    view = view_of(img)
    version = metadata_digest(authenticated_fields(v.meta.to_dict())) if v.meta is not None else ""
    return FrameProof(
        store_id=v.store_id,
        store_version=version,
        view=view,
        view_key=view_key(view),
        rendered_at=rendered_at(img),
        saved_as=None if stamp is None else stamp.saved_as,
        read_as=None if stamp is None else stamp.read_as,
    )


def _age(rendered: str, now: float) -> float | None:
    if not rendered:
        return None
    return now - calendar.timegm(time.strptime(rendered, TIME_FORMAT))


def check_expect(proof: FrameProof, expect: Expect, now: float | None = None) -> None:
    """Refuse (:class:`hevr.VerificationError`, no image) a verified frame that is not what the
    caller expects; a moved frame only when the caller named its store and view (or ``moved``)."""
    if expect.store is not None and proof.store_id != expect.store:
        raise VerificationError(
            f"image: expected a frame of the store {expect.store}, got one of the store "
            f"{proof.store_id}; no image is returned"
        )
    if expect.view is not None and expect.view != proof.view_key:
        raise VerificationError(
            f"image: expected the view {expect.view}, got the view {proof.view_key} "
            f"({proof.describe()}); no image is returned"
        )
    if expect.max_age is not None:
        age = _age(proof.rendered_at, time.time() if now is None else now)
        if age is None or age > expect.max_age or age < -CLOCK_SKEW:  # a render time in the future: not trusted
            got = (
                "one without a render time (stamped before issue 47)"
                if age is None
                else f"one rendered {age:.0f} s ago"
                if age >= 0
                else f"one stamped {-age:.0f} s in the future"
            )
            raise VerificationError(
                f"image: expected a frame rendered at most {expect.max_age:.0f} s ago, got {got}: "
                "an old frame replayed?; no image is returned"
            )
    if proof.moved and not expect.moved and (expect.store is None or expect.view is None):
        raise VerificationError(
            f"image: the key holder saved this verified frame as {proof.saved_as}, and it was read from "
            f"{proof.read_as}: another frame put in this one's place? It proves {proof.what}; "
            "state what you expect (require_verified=hevr.Expect(store=ID, view=KEY); hevr decrypt "
            "--expect-store ID --expect-view KEY), or accept a frame you moved yourself (Expect(moved=True), "
            "--moved); no image is returned"
        )
