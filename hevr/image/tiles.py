"""The image tile layout shared by the render graph and the client's unpacking.

An image of ``width x height`` pixels is cut into square tiles of ``tile`` pixels
(smaller at the right and bottom edges), numbered row-major; inside a tile pixels are
row-major too. A pixel's global index is ``row*width + col``. The render graph reduces and
finishes per tile (:mod:`hevr.rendering.pipeline.graph`), and :class:`hevr.EncryptedImage` unpacks its
per-tile ciphertexts with the same layout.

This is a leaf module (numpy only) so that :mod:`hevr.image` can use it without importing
the rendering package, which itself imports :mod:`hevr.image`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["TileLayout"]


@dataclass(frozen=True)
class TileLayout:
    """Row-major square tiles of an image.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    tile : int
        Tile edge in pixels.

    Examples
    --------
    >>> lay = TileLayout(width=5, height=3, tile=2)
    >>> lay.n_tiles, lay.bounds(5), lay.pixels(5).tolist()
    (6, (2, 3, 4, 5), [14])
    >>> lay.pixels(0).tolist(), lay.ids([0, 4, 14]).tolist()
    ([0, 1, 5, 6], [0, 2, 5])
    """

    width: int
    height: int
    tile: int

    @property
    def tiles_x(self) -> int:
        """Tiles per row."""
        return -(-self.width // self.tile)

    @property
    def tiles_y(self) -> int:
        """Tiles per column."""
        return -(-self.height // self.tile)

    @property
    def n_tiles(self) -> int:
        """Number of tiles."""
        return self.tiles_x * self.tiles_y

    def bounds(self, t: int) -> tuple[int, int, int, int]:
        """Pixel rows ``[r0, r1)`` and columns ``[c0, c1)`` of tile ``t``."""
        ty, tx = divmod(int(t), self.tiles_x)
        r0, c0 = ty * self.tile, tx * self.tile
        return r0, min(r0 + self.tile, self.height), c0, min(c0 + self.tile, self.width)

    def pixels(self, t: int) -> np.ndarray:
        """Global pixel indices (int64) of tile ``t``, row-major inside the tile."""
        r0, r1, c0, c1 = self.bounds(t)
        return (
            np.arange(r0, r1, dtype=np.int64)[:, None] * self.width + np.arange(c0, c1, dtype=np.int64)[None, :]
        ).ravel()

    def ids(self, pixels: Any) -> np.ndarray:
        """Tile index (int64) of each global pixel index."""
        rows, cols = np.divmod(np.asarray(pixels, dtype=np.int64), self.width)
        return (rows // self.tile) * self.tiles_x + cols // self.tile
