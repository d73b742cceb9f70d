"""The routes of ``hevr serve``, one module per resource: :mod:`.meta` (versions, the OpenAPI
document), :mod:`.stores` (what a token may render), :mod:`.render` (frames, streams, the verified
frame's aggregate); :mod:`.base` holds what every endpoint shares (the token, the log line, problem
documents)."""

from __future__ import annotations

from . import meta, render, stores

__all__ = ["ROUTES"]

ROUTES = [*meta.ROUTES, *stores.ROUTES, *render.ROUTES]
