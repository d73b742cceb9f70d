"""The encrypted image the client downloads, decrypts and looks at.

An :class:`EncryptedImage` holds, per image tile, the finished pixel ciphertexts —
packed ``per_pack`` values per ciphertext (Horner, B = 2^pack_bits) unless rendered with
``pack=False`` — plus the public numbers needed to decode them: one common exponent for
every pixel, a public offset, the key fingerprint. File format: ``docs/image-format.md``.
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from ._files import require_file
from ._tiles import TileLayout
from .backends import get_backend
from .crypto.keys import PrivateKey
from .crypto.records import record_width
from .errors import CorruptStoreError, KeyMismatchError, ParameterError

__all__ = ["EncryptedImage", "load_image", "save_png"]

MAGIC = b"HEVRIMG\x01"


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
        every plaintext against it (see :mod:`hevr.rendering.planner`, integrity margin).
    """

    shape: tuple
    exponent: int
    offset: int
    fingerprint: str
    n: int
    tile: int
    pack_bits: int
    per_pack: int
    ciphertexts: list
    hits: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    bound: int | None = None

    def __repr__(self) -> str:
        return (f"EncryptedImage(shape={self.shape}, exponent={self.exponent}, per_pack={self.per_pack}, "
                f"ciphertexts={self.n_ciphertexts}, key={self.fingerprint[:16]}…)")

    @property
    def n_ciphertexts(self) -> int:
        return int(sum(len(c) for c in self.ciphertexts))

    @property
    def channels(self) -> int:
        return self.shape[2] if len(self.shape) == 3 else 1

    def decrypt_mantissas(self, private_key: Any, backend: str | None = None) -> np.ndarray:
        """Integer mantissas (offset removed) as an object array of the image shape; the
        batch decryption runs on ``backend`` (:mod:`hevr.backends`, default ``cpu``)."""
        be = get_backend(backend)
        if not isinstance(private_key, PrivateKey):
            raise ParameterError(f"private_key: expected a hevr.PrivateKey, got {type(private_key).__name__}")
        if private_key.public_key.fingerprint != self.fingerprint:
            raise KeyMismatchError(
                f"private_key: the image was encrypted under key {self.fingerprint[:16]}…, "
                f"got a key with fingerprint {private_key.public_key.fingerprint[:16]}…"
            )

        C = self.channels
        H, W = self.shape[:2]
        out = np.zeros((H, W, C), dtype=object)
        digit_mask = (1 << self.pack_bits) - 1 if self.per_pack > 1 else None
        hits = self.hits if self.hits is not None else np.ones((H, W), bool)
        layout = TileLayout(W, H, self.tile)
        for t in range(layout.n_tiles):
            r0, r1, c0, c1 = layout.bounds(t)
            mask = hits[r0:r1, c0:c1]
            need = int(mask.sum()) * C
            plain = be.decrypt(private_key, be.from_bytes(self.ciphertexts[t]))
            if digit_mask is None:
                vals = plain
            else:
                vals = []
                for m in plain:
                    for _ in range(self.per_pack):
                        vals.append(m & digit_mask)
                        m >>= self.pack_bits
            if len(vals) < need:
                raise CorruptStoreError(f"image tile {t}: {len(vals)} values, expected {need}")
            arr = np.array([v - self.offset for v in vals[:need]], dtype=object)
            block = out[r0:r1, c0:c1, :]
            block[mask] = arr.reshape(-1, C)
        return out[..., 0] if len(self.shape) == 2 else out

    def decrypt(self, private_key: Any, backend: str | None = None) -> np.ndarray:
        """Decrypt to float64 pixel values (batch CRT decryption on ``backend``, then unpacking)."""
        m = self.decrypt_mantissas(private_key, backend)
        scale = Fraction(10) ** self.exponent
        flat = [float(int(v) * scale) for v in m.ravel()]
        return np.array(flat, dtype=np.float64).reshape(self.shape)

    # -- files --------------------------------------------------------------------------
    def _header(self) -> dict:
        return {
            "format": "hevr-encrypted-image", "version": 1, "shape": list(self.shape),
            "exponent": self.exponent, "offset": str(self.offset), "fingerprint": self.fingerprint,
            "n": str(int(self.n)), "tile": self.tile, "pack_bits": self.pack_bits, "per_pack": self.per_pack,
            "width": record_width(self.n),
            "counts": [int(len(c)) for c in self.ciphertexts], "info": self.info,
            "hits": None if self.hits is None else base64.b64encode(np.packbits(self.hits.ravel())).decode(),
        }

    def save(self, path: str | Path) -> None:
        """Write the compact ``.hevr`` file: magic, JSON header length and header, ciphertext bytes."""
        head = json.dumps(self._header(), separators=(",", ":")).encode()
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as fh:
            fh.write(MAGIC)
            fh.write(struct.pack("<I", len(head)))
            fh.write(head)
            for c in self.ciphertexts:
                fh.write(np.ascontiguousarray(c, dtype=np.uint8).tobytes())
        tmp.replace(path)


def load_image(path: str | Path) -> EncryptedImage:
    """Read an image written by :meth:`EncryptedImage.save`."""
    path = require_file(path, "path", "an encrypted image file")
    try:
        blob = path.read_bytes()
    except OSError as exc:
        raise ParameterError(f"path: cannot read {path}: {exc.strerror}") from None
    if not blob.startswith(MAGIC) or len(blob) < len(MAGIC) + 4:
        raise CorruptStoreError(f"{path}: not an hevr encrypted image (bad magic)")
    (hl,) = struct.unpack("<I", blob[len(MAGIC):len(MAGIC) + 4])
    start = len(MAGIC) + 4
    try:
        h = json.loads(blob[start:start + hl])
        if h.get("format") != "hevr-encrypted-image" or h.get("version") != 1:
            raise ValueError("format/version")
        width = int(h["width"])
        counts = [int(c) for c in h["counts"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise CorruptStoreError(f"{path}: malformed image header ({exc})") from None
    body = np.frombuffer(blob, dtype=np.uint8, offset=start + hl)
    if body.size != sum(counts) * width:
        raise CorruptStoreError(f"{path}: truncated: {body.size} ciphertext bytes, expected {sum(counts) * width}")
    hits = None
    if h.get("hits") is not None:
        H, W = (int(x) for x in h["shape"][:2])
        bits = np.unpackbits(np.frombuffer(base64.b64decode(h["hits"]), np.uint8))[: H * W]
        hits = bits.astype(bool).reshape(H, W)
    cts, pos = [], 0
    for c in counts:
        cts.append(body[pos:pos + c * width].reshape(c, width))
        pos += c * width
    return EncryptedImage(shape=tuple(h["shape"]), exponent=int(h["exponent"]), offset=int(h["offset"]),
                          fingerprint=h["fingerprint"], n=int(h["n"]), tile=int(h["tile"]),
                          pack_bits=int(h["pack_bits"]), per_pack=int(h["per_pack"]), ciphertexts=cts,
                          hits=hits, info=h.get("info", {}))


def to_uint8(arr: np.ndarray, window: tuple[float, float] | None = None) -> np.ndarray:
    """Window an image to uint8: grey by (lo, hi) (default 0 .. 99.9th percentile of
    positive pixels); RGB jointly over all channels so colours keep their ratios."""
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise ParameterError(f"arr: expected shape (H, W) or (H, W, 3), got {a.shape}")
    if window is None:
        pos = a[np.isfinite(a) & (a > 0)]
        hi = float(np.percentile(pos, 99.9)) if pos.size else 1.0
        lo = 0.0
    else:
        lo, hi = float(window[0]), float(window[1])
    if not hi > lo:
        hi = lo + 1.0
    return (np.clip((a - lo) / (hi - lo), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save_png(arr: np.ndarray, path: str | Path, window: tuple[float, float] | None = None) -> None:
    """Save a decrypted (or plaintext) image as PNG with sensible windowing.

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> save_png(np.linspace(0, 1, 12).reshape(3, 4), os.path.join(tempfile.mkdtemp(), "a.png"))
    """

    Image.fromarray(to_uint8(arr, window)).save(str(path))
