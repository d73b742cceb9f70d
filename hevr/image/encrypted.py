"""The encrypted image the client downloads, decrypts and looks at: :class:`EncryptedImage`.

An :class:`EncryptedImage` holds, per image tile, the finished pixel ciphertexts — or, finished
on the client (the default, :mod:`hevr.colour`), the ray sums of the stored components, which
:meth:`EncryptedImage.decrypt` colours here —
packed ``per_pack`` values per ciphertext (Horner, B = 2^pack_bits) unless rendered with
``pack=False`` — plus the public numbers needed to decode them: one common exponent for
every pixel, a public offset, the render plan's bound, the key fingerprint.

Nothing wrong reaches the screen: decryption checks every ciphertext and every plaintext
against the bound and the planner's 64-bit integrity margin (:mod:`hevr.image.unpack`, shared
with :mod:`hevr.rendering.pipeline.stream`); every fault is a :class:`hevr.HevrError`. The ``.hevr``
file (:meth:`EncryptedImage.save`, :meth:`EncryptedImage.to_bytes`) is laid out by
:mod:`hevr.image.header` and read back by :mod:`hevr.image.files`; an image is checked
(:func:`hevr.image.checks.check_image`) before it is decrypted or written. An image file may
live on object storage: :meth:`EncryptedImage.save` takes an fsspec URL and its
``storage_options`` (:mod:`hevr.store.paths`); there the file is written in one request, which
an object store makes visible whole or not at all.
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from ..backends import get_backend
from ..colour import colour, colouring_spec, frame_from_sums, scaled_sums
from ..core.validate import check_bool
from ..crypto.keys import PrivateKey
from ..errors import IntegrityError, KeyMismatchError, ParameterError
from ..store.paths import check_storage_options, output_location, write_output
from .checks import check_image
from .header import file_parts
from .proof import Expect
from .provenance import check_provenance, for_file
from .stamp import saved_name
from .unpack import _CORRUPT, tile_values

__all__ = ["EncryptedImage"]

log = logging.getLogger(__name__)


@dataclass
class EncryptedImage:
    """Encrypted render result: shape (H, W) or (H, W, 3), one common exponent.

    Attributes
    ----------
    shape : tuple
    exponent : int
        Every pixel is (m - offset)·10**exponent.
    offset : int
        Public non-negative shift that made every mantissa non-negative (for packing).
    fingerprint : str
        SHA-256 fingerprint of the public key.
    n : int
        Public modulus.
    tile : int
        Tile edge in pixels; tiles are row-major, pixels row-major inside a tile.
    pack_bits, per_pack : int
        Packing base 2**pack_bits and values per ciphertext (1: unpacked).
    ciphertexts : list of np.ndarray
        Per tile, a (P_t, W) uint8 array of big-endian ciphertext records.
    hits : np.ndarray of bool, shape (H, W)
        Public mask of the pixels whose rays hit the volume; only those carry values, the
        others are 0 (which rays miss follows from the public camera and volume shape).
    info : dict
        Public render parameters (mode, sampling, camera, precision, ...).
    bound : int, optional
        The render plan's bound: every value M + offset lies in [0, bound]. Decryption checks
        every plaintext against it (see :mod:`hevr.rendering.planning.planner`, integrity margin); an
        image without it cannot be decrypted or saved.
    finish : {"server", "client"}
        ``"server"``: the values are the finished pixels (the paper's way). ``"client"``: they
        are the ``components`` ray sums of every hit pixel, coloured after decryption on the
        client (:mod:`hevr.colour`).
    channel : str or None
        The stored channel rendered (``"scalar"``, ``"vector"``, ``"gradient"``).
    components : int or None
        Values per hit pixel (None: the shape's channels, 1 or 3).
    samples : np.ndarray of int, shape (H, W), or None
        Samples of every pixel's ray (public geometry; client-finished frames, which divide by it).
    colouring : RenderSpec or None
        The render's colouring (density, transfer function), kept in this process only: it is
        never saved, shown or sent; :meth:`decrypt` applies it unless given another.
    """

    shape: tuple[int, ...]
    exponent: int
    offset: int
    fingerprint: str
    n: int
    tile: int
    pack_bits: int
    per_pack: int
    ciphertexts: list[np.ndarray]
    hits: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    bound: int | None = None
    finish: str = "server"
    channel: str | None = None
    components: int | None = None
    samples: np.ndarray | None = None
    colouring: Any = field(default=None, repr=False, compare=False)
    verification: Any = field(default=None, repr=False, compare=False)
    # (stamp, what it authenticates) of a file that carried the key holder's stamp (hevr.image.stamp)
    stamp: Any = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        return (
            f"EncryptedImage(shape={self.shape}, finish={self.finish!r}, exponent={self.exponent}, "
            f"per_pack={self.per_pack}, ciphertexts={self.n_ciphertexts}, key={self.fingerprint[:16]}…)"
        )

    def __getstate__(self) -> dict[str, Any]:
        """Pickled — to a worker, another process, a file — without the colouring, which stays in
        the process that rendered (``copy.copy`` too; :func:`dataclasses.replace` keeps it)."""
        return dict(self.__dict__, colouring=None)

    @property
    def values_per_pixel(self) -> int:
        """Values each hit pixel carries: its ``components`` (client finishing), else its channels."""
        return int(self.components) if self.components is not None else self.channels

    @property
    def n_ciphertexts(self) -> int:
        return int(sum(len(c) for c in self.ciphertexts))

    @property
    def channels(self) -> int:
        return self.shape[2] if len(self.shape) == 3 else 1

    def decrypt_mantissas(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | Expect | None = None
    ) -> np.ndarray:
        """Integer mantissas (offset removed) as an object array of the image shape.

        ``require_verified`` (True, or the store id that must have been proven): refuse
        (:class:`hevr.VerificationError`) an image that carries no verification record drawn in
        this process or stamped by the key holder (:mod:`hevr.image.stamp`), or one of another store.

        The batch decryption runs on ``backend`` (:mod:`hevr.backends`, default ``cpu``).
        Every ciphertext is checked before it is decrypted and every plaintext after: the
        image is returned only if all of them pass.

        Raises
        ------
        ParameterError, KeyMismatchError
            Not a private key, or the key of another image.
        IntegrityError
            The image carries no ``bound``; a tile holds another number of ciphertexts than
            its hit pixels need (ceil(hits · channels / per_pack)); a ciphertext is not in
            (0, n²); a packed plaintext of L values is not below 2^(pack_bits·L), or a value
            (a base-2^pack_bits digit, or an unpacked plaintext) is not in [0, bound]. The
            message names the tile and the pixels (row, col). A corrupted ciphertext decrypts
            to an essentially uniform element of Z_n and passes with probability below 2^-64
            (the planner's integrity margin, :mod:`hevr.rendering.planning.planner`).
        """
        C = self.values_per_pixel
        H, W = self.shape[:2]
        out = np.zeros((H, W, C), dtype=object)
        offset = int(self.offset)
        for r0, r1, c0, c1, mask, vals in self._checked_tiles(private_key, backend, require_verified):
            block = out[r0:r1, c0:c1, :]
            block[mask] = np.array([v - offset for v in vals], dtype=object).reshape(-1, C)
        return out[..., 0] if C == 1 and len(self.shape) == 2 else out

    def _checked_tiles(
        self, private_key: Any, backend: str | None, require_verified: Any = False
    ) -> Iterator[tuple[int, int, int, int, np.ndarray, list[int]]]:
        """Check the image's numbers now, then return an iterator over the tiles with hits:
        (r0, r1, c0, c1, hit mask, checked values with the offset), in tile order, which raises
        on the first faulty ciphertext (the rules of :meth:`decrypt_mantissas`)."""
        be = get_backend(backend)
        if not isinstance(private_key, PrivateKey):
            raise ParameterError(f"private_key: expected a hevr.PrivateKey, got {type(private_key).__name__}")
        if private_key.public_key.fingerprint != self.fingerprint:
            raise KeyMismatchError(
                f"private_key: the image was encrypted under key {str(self.fingerprint)[:16]}…, "
                f"got a key with fingerprint {private_key.public_key.fingerprint[:16]}…"
            )
        self._check_provenance(private_key, require_verified)
        layout, hits, _ = check_image(self)  # eagerly: before the caller uses any number of the image
        n = private_key.public_key.n
        if int(self.n) != int(n):
            raise IntegrityError(f"image: its modulus n is not the one of its key fingerprint; {_CORRUPT}")
        if self.verification is not None:  # the store's metadata first: it says what every number means
            self.verification.check_metadata(private_key, self)
        tiles = tile_values(self, private_key, be, layout, hits, int(n))
        if self.verification is None:
            return tiles
        listed = list(tiles)  # a verified render: every value checked against the tags before any is used
        W, offset = self.shape[1], int(self.offset)
        ids = [(r0 + rr) * W + c0 + cc for r0, _, c0, _, mask, _ in listed for rr, cc in [np.nonzero(mask)]]
        self.verification.check(
            private_key,
            self,
            np.concatenate(ids) if ids else np.zeros(0, np.int64),
            [v - offset for *_, vals in listed for v in vals],
        )
        return iter(listed)

    def _check_provenance(self, private_key: Any, require_verified: Any) -> None:
        """Who vouches for the verification record (:mod:`hevr.image.provenance`): one drawn in this
        process, or a file's with the key holder's valid stamp; ``require_verified`` (True, or the
        store id that must have been proven) refuses an image without one."""
        check_provenance(
            private_key,
            self,
            require_verified,
            "a store encrypted without verifiable=True, a render with verify=False, server finishing, "
            "or a file saved without the key holder's stamp",
        )

    def decrypt_frame(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | Expect | None = None
    ) -> Any:
        """Decrypt a client-finished image to a :class:`hevr.Frame`: the per-pixel means of the
        stored components, to colour (and re-colour) on this machine (:mod:`hevr.colour`).
        The checks of :meth:`decrypt_mantissas` apply (``IntegrityError`` on any fault, and
        ``require_verified``)."""
        if self.finish != "client":
            raise ParameterError(
                "finish: expected an image rendered with finish='client' (it holds the ray sums "
                "to colour), got one finished on the server: use decrypt()"
            )
        t0 = time.perf_counter()
        K = self.values_per_pixel
        H, W = self.shape[:2]
        sums = np.zeros((H, W, K), dtype=np.float64)
        offset = int(self.offset)
        for r0, r1, c0, c1, mask, vals in self._checked_tiles(private_key, backend, require_verified):
            block = sums[r0:r1, c0:c1, :]
            block[mask] = scaled_sums([v - offset for v in vals], self.exponent).reshape(-1, K)
        stats = dict(self.stats, decrypt_s=time.perf_counter() - t0, ciphertexts=self.n_ciphertexts)
        if self.samples is None:  # refused by check_image before: a client-finished image carries them
            raise IntegrityError(f"image: expected the rays' sample counts, got none; {_CORRUPT}")
        return frame_from_sums(sums, self.samples, str(self.channel), self.colouring, stats)

    def decrypt(
        self,
        private_key: Any,
        backend: str | None = None,
        *,
        mode: str | None = None,
        density: float | None = None,
        nodes: Any = None,
        require_verified: bool | str | Expect | None = None,
    ) -> np.ndarray:
        """Decrypt to float64 pixel values (batch CRT decryption on ``backend``, then unpacking),
        after the checks of :meth:`decrypt_mantissas` (``IntegrityError`` on any fault). Only
        the hit pixels are converted (exactly rounded); pixels whose rays miss stay 0.0.

        A client-finished image (``finish="client"``) is coloured here, on this machine:
        with ``mode`` / ``density`` / ``nodes`` when given, else with the render's own
        colouring (held in this process only), else as an X-ray for the scalar channel
        (:meth:`decrypt_frame` keeps the sums to re-colour). A server-finished image is
        already coloured: giving a colouring is a :class:`hevr.ParameterError`.
        ``require_verified`` as for :meth:`decrypt_mantissas`."""
        if self.finish == "client":
            spec = colouring_spec(str(self.channel), self.values_per_pixel, mode, density, nodes, self.colouring)
            frame = self.decrypt_frame(private_key, backend, require_verified=require_verified)  # checked once
            return colour(frame.means, spec)
        if mode is not None or density is not None or nodes is not None:
            raise ParameterError(
                "mode, density, nodes: expected none for an image finished on the server (its "
                "colouring was applied there); render with finish='client' to colour at decryption"
            )
        C = self.channels
        H, W = self.shape[:2]
        out = np.zeros((H, W, C), dtype=np.float64)
        tiles = self._checked_tiles(private_key, backend, require_verified)  # checks the header numbers first
        offset, scale = int(self.offset), Fraction(10) ** self.exponent
        for r0, r1, c0, c1, mask, vals in tiles:
            block = out[r0:r1, c0:c1, :]
            block[mask] = np.array([float((v - offset) * scale) for v in vals], dtype=np.float64).reshape(-1, C)
        return out[..., 0] if len(self.shape) == 2 else out

    # -- the .hevr file (layout: hevr.image.header; reading: hevr.image.files) ---------------
    def save(
        self,
        path: str | Path,
        *,
        overwrite: bool = False,
        storage_options: dict[str, Any] | None = None,
        private_key: Any = None,
    ) -> None:
        """Write the ``.hevr`` file (format version 3, ``docs/image-format.md``): magic, header
        length, JSON header, ciphertext records, SHA-256 of all of it. The image is checked
        first (``IntegrityError`` for one that :meth:`decrypt` would refuse).

        Never over an existing file unless ``overwrite=True``: otherwise
        :class:`hevr.ExistingFileError`, and the file there (a key, another frame) is not
        touched. Atomic either way: written to a temporary sibling, then linked into place
        (exclusive: no window between a check and the write) or renamed over ``path``
        (``overwrite=True``); a failed write (disk full, file size limit, read-only
        filesystem, …) raises :class:`hevr.FileSystemError` and leaves no temporary and the
        old file as it was. ``path`` may be an fsspec URL, written with ``storage_options`` in
        one request (:func:`hevr.store.paths.write_new_bytes` says what an object store
        guarantees against a racing writer); a local name containing ``://`` is a
        :class:`hevr.ParameterError`.

        A verified image keeps its proof in the file only with the key holder's stamp
        (:mod:`hevr.image.stamp`): with ``private_key`` the image is checked now (as
        :meth:`decrypt` does: :class:`hevr.VerificationError` if it does not verify) and stamped;
        without it, one drawn in this process is written *without* its record (a warning says so:
        a later :meth:`decrypt` could not tell who drew its seed), and one read from a stamped file
        keeps its stamp."""
        so = check_storage_options(storage_options)
        overwrite = check_bool("overwrite", overwrite)
        where = output_location(path)
        img = self._for_file(private_key)
        parts = file_parts(img, private_key, saved_name(where))
        write_output(where, parts, so, overwrite=overwrite, doing="writing the encrypted image")

    def _for_file(self, private_key: Any) -> EncryptedImage:
        """The image as a file holds it (checked; a verified one with the key checked now, or
        without its record when there is no key and no stamp: :meth:`save`)."""
        check_image(self)
        return for_file(self, private_key, lambda key: self.decrypt_mantissas(key, require_verified=Expect(moved=True)))

    def to_bytes(self, private_key: Any = None) -> bytes:
        """The ``.hevr`` file as bytes (what :meth:`save` writes; :func:`hevr.image.image_from_bytes` reads it);
        ``hevr serve`` answers a render with them. Checked first, as :meth:`save` does (and
        ``private_key`` as there)."""
        img = self._for_file(private_key)
        parts = file_parts(img, private_key)
        digest = hashlib.sha256()
        for part in parts:
            digest.update(part)
        return b"".join(bytes(memoryview(p).cast("B")) for p in parts) + digest.digest()
