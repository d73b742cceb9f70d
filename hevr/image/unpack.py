"""Checked unpacking of an encrypted image's tiles: every ciphertext in (0, n²) before it is decrypted,
every packed plaintext narrower than its values' bits and every value in [0, bound] after, so that
nothing wrong reaches the screen. A fault is a :class:`hevr.IntegrityError` naming the tile and
its pixels (row, col). Shared by :class:`hevr.EncryptedImage` and the streamed frames of
:mod:`hevr.rendering.pipeline.stream`.

>>> _unpack_checked([0b0110_0011], 2, 4, 2, 9)
([3, 6], None)
>>> _unpack_checked([0b1100_0011], 2, 4, 2, 9)[1]   # 12 > bound 9: value 1 of ciphertext 0
(False, 0, 1, 2)
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import IntegrityError
from .checks import tile_name

if TYPE_CHECKING:
    from ..crypto.keys import PrivateKey
    from .encrypted import EncryptedImage

__all__ = ["tile_values"]

_CORRUPT = "the image was corrupted or tampered with after the render; no image is returned"


def tile_values(
    img: EncryptedImage, private_key: PrivateKey, be: Any, layout: Any, hits: np.ndarray | None, n: int
) -> Iterator[tuple[int, int, int, int, np.ndarray, list[int]]]:
    """The values of ``img``'s tiles with hits, range-checked, decrypted and unpacked tile by tile:
    (r0, r1, c0, c1, hit mask, values with the offset), in tile order; an :class:`hevr.IntegrityError`
    at the first faulty ciphertext or plaintext (the rules of :meth:`EncryptedImage.decrypt_mantissas`)."""
    C = img.values_per_pixel
    if img.bound is None:  # refused by hevr.image.checks.check_image before
        raise IntegrityError(f"image: expected the render plan's bound, got none; {_CORRUPT}")
    bound, J, b = int(img.bound), int(img.per_pack), int(img.pack_bits)
    nsquare = int(n) * int(n)
    for t in range(layout.n_tiles):
        if not len(img.ciphertexts[t]):
            continue
        r0, r1, c0, c1 = layout.bounds(t)
        mask = np.ones((r1 - r0, c1 - c0), bool) if hits is None else hits[r0:r1, c0:c1]
        need = int(mask.sum()) * C
        recs = be.from_bytes(img.ciphertexts[t])
        bad = be.first_out_of_range(recs, nsquare)
        if bad is not None:
            raise IntegrityError(
                f"{tile_name(layout, t)}: ciphertext {bad} (pixels "
                f"{_pixels(mask, r0, c0, C, bad * J, min(need, bad * J + J))}) is not in "
                f"(0, n²); {_CORRUPT}"
            )
        vals, fault = _unpack_checked(be.decrypt(private_key, recs), need, b, J, bound)
        if fault is not None:
            wide, j, lo, hi = fault
            pix = _pixels(mask, r0, c0, C, lo, hi)
            what = (
                f"ciphertext {j} (pixels {pix}) decrypts to a plaintext wider than its {hi - lo} packed "
                f"values ({b * (hi - lo)} bits)"
                if wide
                else f"pixel {pix} (ciphertext {j}) decrypts to a value outside the render plan's range [0, bound]"
            )
            raise IntegrityError(f"{tile_name(layout, t)}: {what}; {_CORRUPT}")
        yield r0, r1, c0, c1, mask, vals


def _unpack_checked(
    plain: list[int], need: int, pack_bits: int, per_pack: int, bound: int
) -> tuple[list[int], tuple[bool, int, int, int] | None]:
    """The ``need`` values of a tile's plaintexts, and the first fault or None.

    A fault is (wide, ciphertext, first value, end value): ``wide`` when a packed plaintext of L
    values is not below 2^(pack_bits·L) (the whole group), else the one value outside [0, bound].
    Only shifts and comparisons: the cost is negligible next to the decryption.
    """
    if per_pack == 1:
        if plain and (min(plain) < 0 or max(plain) > bound):
            i = next(i for i, m in enumerate(plain) if not 0 <= m <= bound)
            return plain, (False, i, i, i + 1)
        return plain, None
    vals: list[int] = []
    append = vals.append
    digit = (1 << pack_bits) - 1
    for j, m in enumerate(plain):
        lo = j * per_pack
        L = min(per_pack, need - lo)
        if m < 0 or m >> (pack_bits * L):
            return vals, (True, j, lo, lo + L)
        for _ in range(L):
            append(m & digit)
            m >>= pack_bits
    if vals and max(vals) > bound:
        i = next(i for i, v in enumerate(vals) if v > bound)
        return vals, (False, i // per_pack, i, i + 1)
    return vals, None


def _pixels(mask: np.ndarray, r0: int, c0: int, channels: int, lo: int, hi: int) -> str:
    """The pixels (row, col) of a tile's values ``lo:hi`` (hit pixels row-major, channels inside)."""
    where = np.argwhere(mask)[lo // channels : (hi - 1) // channels + 1]
    names = [f"({r0 + int(r)}, {c0 + int(c)})" for r, c in where[:8]]
    more = f", … {len(where)} in all" if len(where) > 8 else ""
    return ", ".join(names) + more
