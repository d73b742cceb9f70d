"""The key holder's side of a packed frame: :class:`PackedImage`, its decryption, decoding and warp.

A packed frame's ciphertexts are, per reduce tile, one combined value per block of S rays and row
(:mod:`hevr.rendering.packed.plan`). Decryption checks every ciphertext (in (0, n²)), every
plaintext (no bit above its last slot: the 64-bit integrity margin; no slot above its ray's
largest possible sum; nothing in the slots of rays outside the frame) before any pixel is formed,
then adds the overlapping slots of neighbouring blocks into exact integer ray sums, undoes the
store's offset (+ offset·W per ray, W the ray's public weight total), divides by the public
sample count and the weight unit, and warps the intermediate image to the camera's pixels
(:meth:`~hevr.rendering.packed.shear.ShearGeometry.warp`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...backends import get_backend
from ...colour import Colouring, Frame
from ...crypto.keys import PrivateKey
from ...errors import IntegrityError, KeyMismatchError, ParameterError
from ...image.provenance import check_provenance
from ...store.packing import INTEGRITY_BITS, unpack_slots
from . import files
from .plan import SlicePlan

log = logging.getLogger(__name__)

__all__ = ["PackedImage", "check_key", "decode"]


@dataclass
class PackedImage:
    """An encrypted X-ray frame of a packed store (``hevr.render`` on a store with ``layout="packed"``).

    Attributes
    ----------
    plan : SlicePlan
        The frame's public plan (geometry, slots, classes, tiles).
    camera : Camera
    fingerprint, n :
        The key's fingerprint and modulus.
    exponent : int
        The scalar channel's exponent (a voxel value is mantissa·10^exponent).
    offset, span : int
        The store's slot offset (lowest mantissa) and mantissa span.
    ciphertexts : list of np.ndarray
        Per tile, (values, W) uint8 big-endian records.
    store_id : str
    stats : dict
        ``ops``: modular operations counted (map, merge, combine), ``rays``, ``ciphertexts``, …
    verification : PackedVerification or None
        The check against the store's tags (:mod:`hevr.rendering.packed.verified`).
    meta : VolumeMetadata or None
        The store's metadata (level 0's, with the owner's MAC on a verifiable store): what a frame
        file holds to rebuild the plan (:meth:`save`).
    level : int
        The pyramid level rendered (``meta.level_meta(level)`` is the frame's volume).
    stamp : tuple or None
        A file's key holder stamp: (stamp, what it authenticates, saved as, read as).
    """

    plan: SlicePlan = field(repr=False)
    camera: Any = field(repr=False)
    fingerprint: str
    n: int = field(repr=False)
    exponent: int
    offset: int
    span: int
    ciphertexts: list[np.ndarray] = field(repr=False)
    store_id: str = ""
    stats: dict[str, Any] = field(default_factory=dict, repr=False)
    verification: Any = field(default=None, repr=False, compare=False)  # a PackedVerification, or None
    meta: Any = field(default=None, repr=False, compare=False)  # the store's VolumeMetadata (frame files)
    level: int = 0
    stamp: Any = field(default=None, repr=False, compare=False)  # a file's (stamp, message, saved as, read as)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.camera.height, self.camera.width)

    @property
    def n_ciphertexts(self) -> int:
        return int(sum(len(c) for c in self.ciphertexts))

    @property
    def verified(self) -> bool:
        """Whether the frame carries a check against the store's tags (drawn in this process), which
        every decryption runs before it forms a pixel (:mod:`hevr.rendering.packed.verified`)."""
        return self.verification is not None

    def _key(self, private_key: Any) -> Any:
        return check_key(private_key, self.fingerprint, self.n, "image")

    def _provenance(self, require_verified: Any, private_key: Any) -> None:
        """Who vouches for the verification record (:func:`hevr.image.provenance.check_provenance`):
        one drawn in this process, or a file's with the key holder's valid stamp, read under the name
        it was saved as; ``require_verified`` (True, or the store id that must have been proven)
        refuses a frame without one."""
        check_provenance(
            private_key,
            self,
            require_verified,
            "a store encrypted with verifiable=False, a render with verify=False, a public-key store, "
            "or a file saved without the key holder's stamp",
        )

    def decrypt_sums(
        self, private_key: PrivateKey, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """The exact integer ray sums Σ w·(m − offset) of the intermediate image, (N_i, N_j) int64:
        a verified frame's values are checked against the store's tags first, and every value's
        slots against their bounds (:func:`decode`), before any sum is returned."""
        key = self._key(private_key)
        self._provenance(require_verified, key)
        if self.verification is not None:  # the metadata first: it says what every number means
            self.verification.check_metadata(key, self.plan, self.fingerprint)
        tiles = self._decrypted_tiles(key, backend)
        sums = decode(self.plan, tiles, self.span)
        if self.verification is not None:
            t0 = time.perf_counter()
            self.verification.check(key, self.plan, [tiles], self.fingerprint)
            self.stats["check_s"] = time.perf_counter() - t0  # the key holder's check, measured
        return sums

    def _decrypted_tiles(self, key: PrivateKey, backend: str | None = None) -> list[Any]:
        """Every tile's plaintexts (residues mod n), after each record's shape and range (0, n²) are
        checked: what :func:`decode` and the tags' check take (the key already checked: :meth:`_key`).
        Not checked against the tags here: callers run the verification before using them."""
        be = get_backend(backend)
        n2 = int(key.public_key.nsquare)
        width = key.public_key.ciphertext_bytes
        tiles = []
        for t, recs in enumerate(self.ciphertexts):
            recs = np.asarray(recs)
            if recs.ndim != 2 or recs.shape[1] != width or recs.dtype != np.uint8:
                raise IntegrityError(
                    f"image: tile {t}: expected (values, {width}) uint8 records, got {recs.shape} "
                    f"{recs.dtype}; no image is returned"
                )
            batch = be.from_bytes(recs)
            bad = be.first_out_of_range(batch, n2)
            if bad is not None:
                raise IntegrityError(
                    f"image: tile {t}: ciphertext {bad} is not in (0, n²): the image was corrupted "
                    "or tampered with; no image is returned"
                )
            tiles.append(be.decrypt(key, batch))
        return tiles

    def decrypt_intermediate(
        self, private_key: PrivateKey, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """The intermediate image (rays along the packing axis × the other axis), float64 X-ray values."""
        sums = self.decrypt_sums(private_key, backend, require_verified=require_verified)
        return self._values(sums)

    def _values(self, sums: np.ndarray) -> np.ndarray:
        """X-ray values (sums + offset·W)·10^exponent / (n·unit), float64, vectorised: every term is an
        exact integer below 2^53 (checked; a float store's huge offsets take Python integers)."""
        plan = self.plan
        W = plan.weight_totals()
        count = plan.geometry.sample_counts(plan.sampling)
        out = np.zeros(sums.shape, np.float64)
        hit = count > 0
        if not hit.any():
            return out
        off, e = int(self.offset), int(self.exponent)
        if abs(off) * int(W.max()) + int(sums.max()) < 1 << 53:
            total = sums[hit].astype(np.float64) + W[hit].astype(np.float64) * float(off)
        else:  # pragma: no cover - offsets beyond 2^30 (float stores with many digits)
            total = np.array([float(int(s) + int(w) * off) for s, w in zip(sums[hit], W[hit])])
        out[hit] = total * 10.0**e / (count[hit].astype(np.float64) * plan.unit)
        return out

    def decrypt(
        self, private_key: PrivateKey, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """The camera's float64 (H, W) image (X-ray: the mean of the samples of every pixel's ray).

        A verified frame (the default on a verifiable store) is checked against the store's tags
        before any pixel is formed (:class:`hevr.VerificationError` and no image otherwise);
        ``require_verified`` (True, or the store id that must have been proven) refuses a frame
        that carries no such check."""
        inter = self.decrypt_intermediate(private_key, backend, require_verified=require_verified)
        geo = self.plan.geometry
        return geo.warp(inter, geo.pixel_coords(self.camera)).reshape(self.shape)

    # -- the frame file (format: hevr.rendering.packed.files; reading: hevr.load_image) --------
    def save(
        self,
        path: str | Path,
        *,
        overwrite: bool = False,
        storage_options: dict[str, Any] | None = None,
        private_key: Any = None,
    ) -> None:
        """Write the packed frame file (``docs/format.md``, "Packed frame files"); ``hevr.load_image``
        reads it back. Never over an existing file unless ``overwrite=True``
        (:class:`hevr.ExistingFileError`), atomic either way; ``path`` may be an fsspec URL
        (``storage_options``), as :meth:`hevr.EncryptedImage.save`.

        A verified frame keeps its record only with the key holder's stamp: with ``private_key`` it is
        checked now (:class:`hevr.VerificationError` if it does not verify) and stamped; without it, a
        record drawn in this process is left out (a warning says so), and one read from a stamped file
        keeps its stamp."""
        files.save_packed(self, path, overwrite=overwrite, storage_options=storage_options, private_key=private_key)

    def to_bytes(self, private_key: Any = None) -> bytes:
        """The packed frame file as bytes (:meth:`save`'s rules; ``hevr.image_from_bytes`` reads them)."""
        return files.packed_bytes(self, private_key)

    def decrypt_frame(
        self, private_key: PrivateKey, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> Frame:
        """A :class:`hevr.Frame` of the X-ray (one component: the mean of every pixel's samples),
        checked as :meth:`decrypt` checks; its ``n_samples`` are the intermediate rays' sample
        counts warped to the pixels, rounded."""
        t0 = time.perf_counter()
        arr = self.decrypt(private_key, backend, require_verified=require_verified)
        geo = self.plan.geometry
        counts = geo.warp(geo.sample_counts(self.plan.sampling).astype(np.float64), geo.pixel_coords(self.camera))
        stats = dict(
            self.stats, decrypt_s=time.perf_counter() - t0, ciphertexts=self.n_ciphertexts, verified=self.verified
        )
        return Frame(
            means=arr[..., None],
            n_samples=np.rint(counts).astype(np.int64).reshape(self.shape),
            channel="scalar",
            colouring=Colouring("xray"),
            stats=stats,
        )

    def __repr__(self) -> str:
        return (
            f"PackedImage(shape={self.shape}, sampling={self.plan.sampling!r}, slots={self.plan.packing.slots}, "
            f"ciphertexts={self.n_ciphertexts}, verified={self.verified}, key={self.fingerprint[:16]}…)"
        )


def check_key(private_key: Any, fingerprint: str, n: int, what: str) -> PrivateKey:
    """``private_key`` itself when it is the key ``what`` (an image, a slice) was encrypted under;
    :class:`hevr.ParameterError` for another type, :class:`hevr.KeyMismatchError` for another key."""
    if not isinstance(private_key, PrivateKey):
        raise ParameterError(f"private_key: expected a hevr.PrivateKey, got {type(private_key).__name__}")
    if private_key.public_key.fingerprint != fingerprint or int(private_key.public_key.n) != int(n):
        raise KeyMismatchError(
            f"private_key: the {what} was encrypted under key {str(fingerprint)[:16]}…, got a key "
            f"with fingerprint {private_key.public_key.fingerprint[:16]}…"
        )
    return private_key


def decode(plan: SlicePlan, tiles: list[list[int]], span: int) -> np.ndarray:
    """The exact ray sums Σ w·u (slot values, before the offset) of the intermediate image,
    (N_i, N_j) int64, from every tile's decrypted values (row-major (row, block) in the tile).

    Raises :class:`hevr.IntegrityError` for a missing or extra tile or value, a value with a bit set
    above its last slot (the integrity margin: a corrupted ciphertext), or a slot above the largest
    sum its ray can have (span·W of that ray, which is 0 for a ray that reads no voxel)."""
    g, S, K = plan.geometry, plan.packing.slots, plan.packing.slot_bits
    o_max, n_out = plan.classes - 1, plan.slots_out
    ni, nj = g.size
    sums = np.zeros((ni, nj), np.int64)
    lo, hi = plan.block_rays()  # every slot's ray, the frame's and its blocks' neighbours
    W = plan.weight_totals((lo, hi))
    # every slot's bound, span·W (below 2^K ≤ 2^62 on a frame the planner let through; Python ints otherwise)
    top = W * int(span) if not W.size or int(W.max()) * int(span) < 1 << 62 else W.astype(object) * int(span)
    limit = 1 << (n_out * K)
    if len(tiles) != plan.n_tiles:
        raise IntegrityError(f"image: expected {plan.n_tiles} tiles, got {len(tiles)}; {_CORRUPT}")
    for t, vals in enumerate(tiles):
        j0, j1, b0, b1 = plan.tile_bounds(t)
        if len(vals) != (j1 - j0) * (b1 - b0):
            raise IntegrityError(
                f"image: tile {t} holds {len(vals)} values, expected {(j1 - j0) * (b1 - b0)}; {_CORRUPT}"
            )
        if any(not 0 <= int(v) < limit for v in vals):
            raise IntegrityError(
                f"image: a value of tile {t} has bits set above its {n_out} slots of {K} bits "
                f"(the {INTEGRITY_BITS}-bit integrity margin); {_CORRUPT}"
            )
        slots = unpack_slots(vals, n_out, K).reshape(j1 - j0, b1 - b0, n_out)
        Bs = np.arange(b0, b1) + plan.block_range[0]
        ray = S * Bs[:, None] + np.arange(n_out)[None, :] - o_max - plan.m_lo  # (blocks, slots): the ray of each slot
        ext, frame = ray - lo, ray - g.i_range[0]
        cols = np.arange(j0, j1)
        if (slots > top[ext[None, :, :], cols[:, None, None]]).any():
            raise IntegrityError(f"image: tile {t} has a slot above the largest sum its ray can have; {_CORRUPT}")
        inside = (frame >= 0) & (frame < ni)
        rows = np.broadcast_to(frame[None, :, :], slots.shape)[:, inside]
        np.add.at(sums, (rows, np.broadcast_to(cols[:, None], rows.shape)), slots[:, inside])
    return sums


_CORRUPT = "the image was corrupted or tampered with; no image is returned"
