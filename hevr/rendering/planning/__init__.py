"""Planning: a request checked once, and every quantity of the render bounded before any ciphertext.

The data flows through this room in this order:

=================  =============================================================
``modes``          ``RenderSpec``: mode, sampling, channels, combination matrix
``request``        a request checked once where it enters; a view moved to a pyramid level
``planner``        overflow planning: fixed-point digits, packing bounds (``RenderPlan``)
``bounds``         ``error_bound``: a decrypted pixel against ``render_plain``
=================  =============================================================

Before: :mod:`hevr.rendering.geometry` (the rays a plan counts). Next:
:mod:`hevr.rendering.pipeline` runs the plan on ciphertexts.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ...core.lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr.core.lazy)
    from .bounds import error_bound
    from .modes import RenderSpec, combination_matrix, make_spec
    from .planner import RenderPlan, check_render_size, plan_render
    from .request import at_level, check_request

__all__ = [
    "RenderPlan",
    "RenderSpec",
    "at_level",
    "check_render_size",
    "check_request",
    "combination_matrix",
    "error_bound",
    "make_spec",
    "plan_render",
]

# Name -> submodule, imported on first use. Equal to the TYPE_CHECKING imports above.
_LAZY = {
    ".bounds": ("error_bound",),
    ".modes": ("RenderSpec", "combination_matrix", "make_spec"),
    ".planner": ("RenderPlan", "check_render_size", "plan_render"),
    ".request": ("at_level", "check_request"),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
