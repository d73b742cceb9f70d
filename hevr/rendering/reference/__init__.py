"""The plaintext reference: the same rendering equations on an unencrypted volume, in plain numpy.

=================  =============================================================
``plain``          ``render_plain`` / ``render_slice_plain``: a direct, vectorised ray marcher
=================  =============================================================

It shares the request's geometry (:mod:`hevr.rendering.geometry`) and modes and size checks
(:mod:`hevr.rendering.planning`) with the encrypted path, and none of its pipeline
(:mod:`hevr.rendering.pipeline`): what the encrypted render is checked against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ...core.lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr.core.lazy)
    from .plain import render_plain, render_slice_plain

__all__ = ["render_plain", "render_slice_plain"]

# Name -> submodule, imported on first use. Equal to the TYPE_CHECKING imports above.
_LAZY = {
    ".plain": ("render_plain", "render_slice_plain"),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
