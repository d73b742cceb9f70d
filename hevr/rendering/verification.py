"""The record of a verified render and the key holder's check of it (:mod:`hevr.rendering.verify`).

A :class:`Verification` is what the client keeps of the round: the tag aggregate A the server
returned, the seed of the coefficients drawn here, and the public geometry of the view; a ``.hevr``
file carries it (:meth:`Verification.to_dict`, :meth:`Verification.from_dict`). Decryption calls
:meth:`Verification.check`: the store's metadata under the owner's MAC, the image's public fields,
then D(A) ≡ α·Σρ·S' + Σρ·B (mod n), Σρ·B from :mod:`hevr.rendering.tag_betas`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..crypto.tags import aggregate_holds, coefficients_at
from ..errors import HevrError, IntegrityError, VerificationError
from ..store.authenticity import authenticated_fields, check_metadata_mac
from ..store.known import record_verified
from ..store.metadata import VolumeMetadata
from ..volume.pyramid import MAX_LEVELS
from .geometry.plane import view_from_dict
from .geometry.rays import RaySet, cast_rays
from .tag_betas import beta_sum

log = logging.getLogger(__name__)

__all__ = ["Verification"]


@dataclass(frozen=True, repr=False)
class Verification:
    """What the client keeps of a verified render: the aggregate A, the seed of the coefficients
    and the public geometry to recompute Σρ·B (no secret: A is a ciphertext)."""

    aggregate: int
    seed: bytes
    store_id: str
    channel: str
    shape: tuple
    spacing: tuple
    brick: tuple
    camera: Any
    sampling: str
    step: float
    digits: int
    components: int
    n: int
    level: int = 0
    base_shape: tuple = ()
    exponent: int = 0
    server_s: float = 0.0
    meta: Any = None  # the store's (level-0) VolumeMetadata the render used; its owner's MAC is checked
    drawn_here: bool = False  # the seed was drawn in this process (not read from a file)
    known_name: str = dataclasses.field(default="", compare=False)  # rendered under (known stores; not in files)
    drawn_at: float = 0.0  # when (seconds since the epoch; a file's stamp keeps it as rendered_at)

    def __repr__(self) -> str:
        return f"Verification({self.channel}, {self.components} per ray, seed …)"

    @classmethod
    def of(
        cls,
        ev: Any,
        camera: Any,
        sampling: str,
        step: float,
        digits: int,
        channel: str,
        *,
        exponent: int,
        aggregate: int,
        seed: bytes,
        server_s: float = 0.0,
    ) -> Verification:
        """The record of a round on the volume (or level view) ``ev`` as the key holder knows it:
        every field but the aggregate comes from this process, never from the server — with the
        store's metadata this process rendered with, whose owner's MAC :meth:`check` verifies."""
        base = ev.base if ev.level else ev.meta  # level 0's VolumeMetadata
        return cls(
            aggregate=int(aggregate),
            seed=seed,
            store_id=ev.meta.store_id,
            channel=channel,
            shape=ev.shape,
            spacing=ev.spacing,
            brick=ev.brick,
            camera=camera,
            sampling=sampling,
            step=step,
            digits=digits,
            components=ev.meta.components(channel),
            n=int(ev.public_key.n),
            level=ev.level,
            exponent=int(exponent),
            base_shape=tuple(base.shape),
            server_s=server_s,
            meta=base,
            drawn_here=True,
            drawn_at=time.time(),
            known_name=str(ev.path),
        )

    def to_dict(self) -> dict[str, Any]:
        """The record a ``.hevr`` file carries (public: a ciphertext, a seed, the request's geometry)."""
        return {
            "version": 2,
            "aggregate": str(self.aggregate),
            "seed": self.seed.hex(),
            "store_id": self.store_id,
            "channel": self.channel,
            "shape": [int(x) for x in self.shape],
            "spacing": [float(x) for x in self.spacing],
            "brick": [int(x) for x in self.brick],
            "view": self.camera.to_dict(),
            "sampling": self.sampling,
            "step": float(self.step),
            "digits": int(self.digits),
            "components": int(self.components),
            "level": int(self.level),
            "base_shape": [int(x) for x in (self.base_shape or self.shape)],
            "exponent": int(self.exponent),
            "metadata": self.meta.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Any, n: int, where: str = "image") -> Verification:
        """Parse :meth:`to_dict`'s record under the image's modulus ``n``;
        :class:`hevr.IntegrityError` names the first wrong field."""

        def bad(name: str, expected: str) -> IntegrityError:
            got = d.get(name) if isinstance(d, dict) else d
            return IntegrityError(
                f"{where}: header field 'verification.{name}': expected {expected}, got {str(got)[:80]!r}"
            )

        fields = {
            "version",
            "aggregate",
            "seed",
            "store_id",
            "channel",
            "shape",
            "spacing",
            "brick",
            "view",
            "sampling",
            "step",
            "digits",
            "components",
            "level",
            "base_shape",
            "exponent",
            "metadata",
        }
        if not isinstance(d, dict) or set(d) != fields:
            raise bad(
                "version",
                f"an object with exactly {sorted(fields)} (version 2; a frame verified before "
                "hevr bound the store's metadata: render it again)",
            )
        if d["version"] != 2 or type(d["version"]) is not int:
            raise bad("version", "2")
        agg = d["aggregate"]
        if not (isinstance(agg, str) and agg.isdigit() and len(agg) <= 2 * len(str(n)) and 0 < int(agg) < n * n):
            raise bad("aggregate", "a decimal string of a ciphertext in (0, n²)")
        seed = d["seed"]
        if not (isinstance(seed, str) and len(seed) == 64 and all(c in "0123456789abcdef" for c in seed)):
            raise bad("seed", "64 lower-case hex digits")
        if not (isinstance(d["store_id"], str) and len(d["store_id"]) == 16):
            raise bad("store_id", "a store id of 16 hex digits")
        if d["channel"] not in ("scalar", "vector", "gradient"):
            raise bad("channel", "'scalar', 'vector' or 'gradient'")
        for name, kind in (("shape", int), ("brick", int), ("spacing", float), ("base_shape", int)):
            v = d[name]
            if not (
                isinstance(v, list)
                and len(v) == 3
                and all(type(x) is kind or (kind is float and type(x) is int) for x in v)
                and all(x > 0 for x in v)
            ):
                raise bad(name, f"three positive {kind.__name__}s")
        if d["sampling"] not in ("nearest", "trilinear"):
            raise bad("sampling", "'nearest' or 'trilinear'")
        if not (type(d["step"]) in (int, float) and 0 < d["step"] < float("inf")):
            raise bad("step", "a positive number")
        for name, lo, hi in (("digits", 0, 12), ("components", 0, 64), ("level", 0, MAX_LEVELS), ("exponent", -64, 64)):
            if type(d[name]) is not int or not lo <= d[name] <= hi:
                raise bad(name, f"an integer in [{lo}, {hi}]")
        try:
            view = view_from_dict(d["view"])
        except HevrError as exc:
            raise bad("view", f"a camera or plane ({exc})") from None
        try:
            meta = VolumeMetadata.from_dict(d["metadata"], where=f"{where}: verification.metadata")
        except HevrError as exc:
            raise bad("metadata", f"a verifiable store's metadata ({exc})") from None
        if not meta.tags or meta.store_id != d["store_id"] or int(meta.n) != int(n):
            raise bad("metadata", "the metadata of the verifiable store the record names, under the image's key")
        if tuple(d["base_shape"]) != meta.shape:
            raise bad("base_shape", f"the store's shape {list(meta.shape)}")
        if d["level"] > len(meta.levels) and d["level"]:
            raise bad("level", f"a level of the store's pyramid (0 to {len(meta.levels)})")
        lm = meta.level_meta(d["level"]) if d["level"] else meta
        if tuple(d["shape"]) != tuple(lm.shape) or tuple(d["brick"]) != tuple(lm.brick):
            raise bad(
                "shape", f"the shape {list(lm.shape)} and brick {list(lm.brick)} of level {d['level']} of the store"
            )
        return cls(
            aggregate=int(agg),
            seed=bytes.fromhex(seed),
            store_id=d["store_id"],
            channel=d["channel"],
            shape=tuple(d["shape"]),
            spacing=tuple(float(x) for x in d["spacing"]),
            brick=tuple(d["brick"]),
            camera=view,
            sampling=d["sampling"],
            step=float(d["step"]),
            digits=d["digits"],
            components=d["components"],
            n=int(n),
            level=d["level"],
            base_shape=tuple(d["base_shape"]),
            exponent=d["exponent"],
            meta=meta,
        )

    def beta_sum(self, private_key: Any, rays: RaySet | None = None) -> int:
        """Σ_{r,k} ρ_{r,k}·B_{r,k} mod n from the public geometry and the PRF
        (:func:`hevr.rendering.tag_betas.beta_sum`; ``rays``: the view's, cast here by default)."""
        rays = rays if rays is not None else cast_rays(self.camera, self.shape, self.spacing, self.step)
        return beta_sum(self, private_key, rays)

    def check_metadata(self, private_key: Any, image: Any) -> None:
        """Raise :class:`hevr.VerificationError` unless the store's metadata this render used carries
        the owner's MAC (:mod:`hevr.store.authenticity`) and the record's geometry, channel and key
        are the ones it gives at the record's level."""
        m = self.meta
        if m is None or not check_metadata_mac(private_key, authenticated_fields(m.to_dict()), m.auth):
            raise VerificationError(
                "store metadata: expected the owner's MAC over the shape, spacing, brick, channels, exponents, digits, "
                f"value range and store id, got {'none' if m is None or not m.auth else 'a MAC that does not match'}: "
                "the store's public metadata was altered (or is not this key's); no image is returned"
            )
        lm = m.level_meta(self.level) if self.level else m
        want = (
            m.store_id,
            int(m.n),
            m.fingerprint,
            tuple(lm.shape),
            tuple(float(x) for x in lm.spacing),
            tuple(lm.brick),
            tuple(m.shape),
            lm.components(self.channel),
        )
        got = (
            self.store_id,
            int(self.n),
            image.fingerprint,
            tuple(self.shape),
            tuple(float(x) for x in self.spacing),
            tuple(self.brick),
            tuple(self.base_shape),
            self.components,
        )
        if want != got or getattr(lm, self.channel) is None:
            raise VerificationError(
                "image: its store id, key, shape, spacing, brick or channel are not those of the "
                "store's authenticated metadata; no image is returned"
            )

    def check(self, private_key: Any, image: Any, ray_ids: np.ndarray, sums: list[int]) -> None:
        """Raise :class:`hevr.VerificationError` unless the ``image``'s public fields are those of
        this view (shape, channel, exponent, components, sample counts, hit mask) and D(A) = α·Σρ·S' + Σρ·B
        (mod n); ``sums`` are its decrypted ray sums S' (offset removed), ``K`` per ray of
        ``ray_ids``."""
        t0 = time.perf_counter()
        self.check_metadata(private_key, image)
        K = self.components
        rays = cast_rays(self.camera, self.shape, self.spacing, self.step)
        H, W = self.camera.height, self.camera.width
        samples = np.asarray(rays.n_samples).reshape(H, W)
        same = (
            tuple(image.shape[:2]) == (H, W)
            and image.finish == "client"
            and image.channel == self.channel
            and int(image.exponent) == self.exponent
            and int(image.components or 0) == K
            and image.samples is not None
            and image.hits is not None
            and np.array_equal(np.asarray(image.samples).reshape(H, W), samples)
            and np.array_equal(np.asarray(image.hits, bool), samples > 0)
        )
        if not same:
            raise VerificationError(
                "image: its shape, channel, exponent, components, sample counts or hit mask are "
                f"not those of the verified view ({W}x{H}, channel {self.channel!r}); no image is "
                "returned"
            )
        ids = (np.asarray(ray_ids, np.int64)[:, None] * K + np.arange(K)).reshape(-1)
        if ids.size != len(sums):
            raise VerificationError(
                f"image: expected {ids.size} ray sums for its hit pixels, got {len(sums)}; no image is returned"
            )
        rho = coefficients_at(self.seed, ids).tolist()
        s_sum = sum(int(r) * int(s) for r, s in zip(rho, sums))
        holds = aggregate_holds(private_key, s_sum, self.beta_sum(private_key, rays), self.aggregate)
        log.info("verification: %.3f s on the client", time.perf_counter() - t0)
        if not holds:
            raise VerificationError(
                "image: the render does not verify: its ray sums are not the ones the store's tags certify (an "
                "altered, substituted or replayed image or store, or a server that did not render as asked); "
                "no image is returned"
            )
        record_verified(self, private_key)  # proven: the store under its name is the one the key holder knows
