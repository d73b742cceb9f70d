"""The ``hevr`` command line: one module per concern.

=================  =============================================================
``main``           the argument parser and dispatch (``hevr`` entry point)
``commands``       keygen, encrypt, render, decrypt, info
``util``           shared argument types, progress, key/volume loading for commands
``demo``           ``hevr demo``: the whole data path on a phantom
``sheet``          the demo's contact sheet
``bench``          ``hevr bench`` (the engine is :mod:`hevr._bench`)
=================  =============================================================
"""

from __future__ import annotations

from .main import main

__all__ = ["main"]
