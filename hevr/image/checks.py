"""The checks of every number an encrypted image carries (:mod:`hevr.image`), shared by a file's
header (:mod:`hevr.image.header`, :class:`hevr.CorruptStoreError`) and an
image in memory before it is decrypted or saved (:class:`hevr.IntegrityError`): the render
plan's numbers against the integrity margin (:func:`check_numbers`), finish / channel /
components (:func:`check_frame`) and every tile's ciphertext count (:func:`check_image`).
"""

from __future__ import annotations

import numbers
import sys
from typing import Any, NoReturn

import numpy as np

from ..core.limits import MAX_IMAGE_PIXELS, fits_float, integrity_bits
from ..core.validate import is_decimal
from ..crypto.records import record_width
from ..errors import HevrError, IntegrityError
from .tiles import TileLayout

__all__ = [
    "CHANNELS",
    "FINISHES",
    "MAX_COMPONENTS",
    "MAX_EXPONENT",
    "MAX_PIXELS",
    "Fields",
    "check_frame",
    "check_image",
    "check_numbers",
    "check_shape",
    "expected_counts",
    "tile_hit_counts",
    "tile_name",
]

MAX_PIXELS = MAX_IMAGE_PIXELS  # H·W of one image: 67 million pixels, the renderer's cap too
MAX_EXPONENT = 1000  # |exponent|: 10**exponent must stay cheap
FINISHES = ("server", "client")
CHANNELS = ("scalar", "vector", "gradient")
MAX_COMPONENTS = 64  # values per hit pixel of a client-finished frame (the vector encoding's length)


def _show(value: Any) -> str:
    """A short repr for messages (a hostile header may hold megabytes in one field)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:45] + f"… ({len(text)} chars)"


def _clip(text: str) -> str:
    return text if len(text) <= 80 else text[:65] + f"… ({len(text)} chars)"


def _kind(value: Any) -> str:
    return "null" if value is None else type(value).__name__


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


class Fields:
    """Where a check runs and what it raises: a file's header (``CorruptStoreError``) or an
    image in memory (``IntegrityError``)."""

    def __init__(self, where: str, error: type[HevrError], label: str) -> None:
        self.where, self.error, self.label = where, error, label

    def fail(self, name: str, expected: str, got: Any = None, *, raw: str | None = None) -> NoReturn:
        shown = raw if raw is not None else _show(got)
        raise self.error(f"{self.where}: {self.label} {name!r}: expected {expected}, got {shown}")

    def integer(self, name: str, value: Any, lo: int | None = None, hi: int | None = None) -> int:
        if not _is_int(value):
            self.fail(name, _int_text(lo, hi), raw=f"{_show(value)} ({_kind(value)})")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            self.fail(name, _int_text(lo, hi), value)
        return int(value)

    def decimal(self, name: str, value: Any, max_digits: int) -> int:
        """A canonical decimal string (ASCII digits, no sign, no leading zero), length checked
        before any conversion."""
        if not isinstance(value, str):
            self.fail(name, "a decimal string", raw=f"{_show(value)} ({_kind(value)})")
        if not 1 <= len(value) <= max_digits:
            self.fail(name, f"a decimal string of 1 to {max_digits} digits", raw=f"{len(value)} characters")
        if not is_decimal(value, max_digits) or (len(value) > 1 and value[0] == "0"):
            self.fail(name, "a decimal string (digits 0-9, no sign, no leading zero)", value)
        return int(value)


def _int_text(lo: int | None, hi: int | None) -> str:
    if lo is not None and hi is not None:
        return f"an int in [{lo}, {hi}]"
    if lo is not None:
        return f"an int >= {lo}"
    return "an int" if hi is None else f"an int <= {hi}"


# -- rules shared by files and images in memory ---------------------------------------------
def check_shape(ctx: Fields, shape: Any) -> tuple[int, ...]:
    """[H, W] or [H, W, 3] of positive ints with H·W <= 2^26."""
    if not isinstance(shape, (list, tuple)) or len(shape) not in (2, 3):
        ctx.fail("shape", "a list [H, W] or [H, W, 3]", shape)
    if not all(_is_int(x) and x >= 1 for x in shape) or (len(shape) == 3 and shape[2] != 3):
        ctx.fail("shape", "a list [H, W] or [H, W, 3] of positive ints", list(shape))
    H, W = int(shape[0]), int(shape[1])
    if H * W > MAX_PIXELS:
        ctx.fail("shape", f"at most {MAX_PIXELS} pixels (H·W)", shape)
    return (H, W) if len(shape) == 2 else (H, W, 3)


def check_numbers(
    ctx: Fields, *, n: int, exponent: Any, bound: Any, offset: Any, tile: Any, pack_bits: Any, per_pack: Any
) -> None:
    """The render plan's numbers against each other and against the integrity margin:
    |exponent| <= 1000, 0 <= offset <= bound, bits(bound) <= room, every pixel
    (m − offset)·10^exponent (m in [0, bound]) a finite float64
    (:func:`hevr.core.limits.fits_float`), tile >= 1, pack_bits >= 0,
    per_pack >= 1, pack_bits >= 1 when per_pack > 1, pack_bits·per_pack <= room and
    bound < 2^pack_bits when pack_bits > 0, with room = bits(n) − 1 − κ (κ =
    :func:`hevr.core.limits.integrity_bits`, the planner's margin)."""
    kappa = integrity_bits(int(n).bit_length())
    room = int(n).bit_length() - 1 - kappa
    ctx.integer("exponent", exponent, -MAX_EXPONENT, MAX_EXPONENT)
    if room < 1:
        ctx.fail(
            "n",
            f"a modulus of at least {kappa + 2} bits (the integrity margin keeps {kappa})",
            raw=f"{int(n).bit_length()} bits",
        )
    bound = ctx.integer("bound", bound, 0)
    if bound.bit_length() > room:
        ctx.fail(
            "bound",
            f"an int below 2^{room} (bits(n) − 1 − {kappa}: the integrity margin)",
            raw=f"an int of {bound.bit_length()} bits",
        )
    offset = ctx.integer("offset", offset, 0, bound)
    if not fits_float(max(offset, bound - offset), exponent):
        ctx.fail(
            "exponent",
            f"an int with max(offset, bound − offset)·10^exponent <= {sys.float_info.max:.4g} "
            f"(every pixel a finite float64)",
            exponent,
        )
    ctx.integer("tile", tile, 1, MAX_PIXELS)
    pack_bits = ctx.integer("pack_bits", pack_bits, 0, room)
    per_pack = ctx.integer("per_pack", per_pack, 1, room)
    if per_pack > 1 and pack_bits < 1:
        ctx.fail("pack_bits", "an int >= 1 when per_pack > 1", pack_bits)
    if pack_bits * per_pack > room:
        ctx.fail(
            "per_pack",
            f"pack_bits·per_pack <= {room} (bits(n) − 1 − {kappa})",
            raw=f"{per_pack} (pack_bits·per_pack = {pack_bits * per_pack})",
        )
    if pack_bits and bound.bit_length() > pack_bits:
        ctx.fail("bound", f"an int below 2^pack_bits = 2^{pack_bits}", raw=f"an int of {bound.bit_length()} bits")


def _sizes(total: int, tile: int) -> np.ndarray:
    out = np.full(-(-total // tile), tile, np.int32)
    if total % tile:
        out[-1] = total % tile
    return out


def tile_hit_counts(hits: np.ndarray | None, shape: tuple[int, int], tile: int) -> np.ndarray:
    """Hit pixels of every tile (row-major tile order), int32 (H·W <= 2^26); ``hits=None``
    means all pixels hit. Sums over reshaped views: no copy of the mask.

    >>> tile_hit_counts(np.eye(3, dtype=bool), (3, 3), 2).tolist()
    [2, 0, 0, 1]
    """
    H, W = shape
    if hits is None:
        return np.outer(_sizes(H, tile), _sizes(W, tile)).ravel()
    out = np.zeros((-(-H // tile), -(-W // tile)), np.int32)
    fy, fx = H // tile, W // tile  # full tiles per column and per row
    Hf, Wf = fy * tile, fx * tile
    if fy and fx:
        hits[:Hf, :Wf].reshape(fy, tile, fx, tile).sum(axis=(1, 3), dtype=np.int32, out=out[:fy, :fx])
    if Hf < H and fx:
        hits[Hf:, :Wf].reshape(H - Hf, fx, tile).sum(axis=(0, 2), dtype=np.int32, out=out[fy, :fx])
    if Wf < W and fy:
        hits[:Hf, Wf:].reshape(fy, tile, W - Wf).sum(axis=(1, 2), dtype=np.int32, out=out[:fy, fx])
    if Hf < H and Wf < W:
        out[fy, fx] = hits[Hf:, Wf:].sum()
    return out.ravel()


def expected_counts(hit_counts: np.ndarray, channels: int, per_pack: int) -> np.ndarray:
    """Ciphertexts of every tile: ceil(hit pixels · channels / per_pack)."""
    return -(-hit_counts * channels // per_pack)


def tile_name(layout: TileLayout, t: int) -> str:
    """``"image tile 3 (rows 0-7, cols 8-15)"``."""
    r0, r1, c0, c1 = layout.bounds(t)
    return f"image tile {t} (rows {r0}-{r1 - 1}, cols {c0}-{c1 - 1})"


def check_image(img: Any) -> tuple[TileLayout, np.ndarray | None, int]:
    """Check an image in memory before decryption or saving (:class:`hevr.IntegrityError`).

    Returns its tile layout, hits mask (or None) and record width. Checks the numbers as
    :func:`check_numbers`, the hits mask, one ciphertext array per tile and every tile's
    ciphertext count.
    """
    ctx = Fields("image", IntegrityError, "field")
    if img.bound is None:
        raise IntegrityError(
            "image: it carries no bound (the render plan's range of every value), so its "
            "decrypted values cannot be checked; render it again with this hevr"
        )
    shape = check_shape(ctx, tuple(img.shape) if isinstance(img.shape, (list, tuple)) else img.shape)
    if not _is_int(img.n) or img.n < 3:
        ctx.fail("n", "an int modulus", raw=_kind(img.n))
    check_numbers(
        ctx,
        n=int(img.n),
        exponent=img.exponent,
        bound=img.bound,
        offset=img.offset,
        tile=img.tile,
        pack_bits=img.pack_bits,
        per_pack=img.per_pack,
    )
    H, W = shape[:2]
    hits = img.hits
    if hits is not None and not (isinstance(hits, np.ndarray) and hits.dtype == bool and hits.shape == (H, W)):
        ctx.fail(
            "hits",
            f"a bool array of shape ({H}, {W}) or None",
            raw=f"{type(hits).__name__} {getattr(hits, 'dtype', '')}{getattr(hits, 'shape', '')}",
        )
    per_pixel = check_frame(ctx, img.finish, img.channel, img.components, shape)
    if img.finish == "client":
        samples = img.samples
        if not (isinstance(samples, np.ndarray) and samples.dtype.kind in "iu" and samples.shape == (H, W)):
            ctx.fail(
                "samples",
                f"an int array of shape ({H}, {W}) (client finishing divides by it)",
                raw=f"{type(samples).__name__} {getattr(samples, 'dtype', '')}{getattr(samples, 'shape', '')}",
            )
        if samples.size and (samples.min() < 0 or samples.max() >= 2**32):
            ctx.fail("samples", "counts in [0, 2^32)", raw="others")
        if hits is None or not np.array_equal(hits, samples > 0):
            ctx.fail("hits", "the pixels with samples > 0", raw="another mask")
    layout = TileLayout(W, H, int(img.tile))
    width = record_width(int(img.n))
    cts = img.ciphertexts
    if not isinstance(cts, (list, tuple)) or len(cts) != layout.n_tiles:
        ctx.fail(
            "ciphertexts",
            f"a list of {layout.n_tiles} arrays (one per tile)",
            raw=f"{_kind(cts)} of {len(cts) if isinstance(cts, (list, tuple)) else '?'}",
        )
    want = expected_counts(tile_hit_counts(hits, (H, W), int(img.tile)), per_pixel, int(img.per_pack))
    for t, (c, e) in enumerate(zip(cts, want.tolist())):
        if not (isinstance(c, np.ndarray) and c.dtype == np.uint8 and c.ndim == 2 and c.shape[1] == width):
            raise IntegrityError(
                f"{tile_name(layout, t)}: ciphertexts: expected a uint8 array of shape "
                f"({e}, {width}), got {type(c).__name__} {getattr(c, 'dtype', '')}"
                f"{getattr(c, 'shape', '')}"
            )
        if c.shape[0] != e:
            raise IntegrityError(
                f"{tile_name(layout, t)}: expected {e} ciphertexts (its hit pixels × channels / "
                f"per_pack, rounded up), got {c.shape[0]}: the image was corrupted or tampered "
                f"with; no image is returned"
            )
    return layout, hits, width


def check_frame(ctx: Fields, finish: Any, channel: Any, components: Any, shape: tuple[int, ...]) -> int:
    """``finish``, ``channel`` and ``components`` against each other and the shape; returns the
    values per hit pixel. Server finishing: the shape's channels (1 or 3), channel any or None
    (a version-2 file); client finishing: 1 for the scalar channel, else 2..64."""
    if finish not in FINISHES:
        ctx.fail("finish", "'server' or 'client'", finish)
    channels = 3 if len(shape) == 3 else 1
    if finish == "server":
        if channel is not None and channel not in CHANNELS:
            ctx.fail("channel", f"one of {list(CHANNELS)} or null", channel)
        if components is not None:
            ctx.integer("components", components, channels, channels)
        return channels
    if channel not in CHANNELS:
        ctx.fail("channel", f"one of {list(CHANNELS)}", channel)
    if channel == "scalar":
        return ctx.integer("components", components, 1, 1)
    return ctx.integer("components", components, 2, MAX_COMPONENTS)
