"""The ``hevr`` command line: one module per concern.

=================  =============================================================
``main``           the argument parser and dispatch (``hevr`` entry point)
``keys``           keygen, convert-key (hevr and python-paillier key files)
``commands``       encrypt, render, recolour, decrypt, info, upgrade-store
``slice``          ``hevr slice``: encrypted planes (axial, coronal, sagittal, oblique)
``pyramid``        ``hevr pyramid``: the encrypted multi-resolution pyramid
``options``        argparse value types (one checker per option kind)
``exits``          the exit-status rule and the CLI's words in error messages
``util``           shared checks, progress, key/volume loading, Dask clients, formatting
``demo``           ``hevr demo``: the whole data path on a phantom
``sheet``          the demo's contact sheet
``bench``          ``hevr bench`` (the engine is :mod:`hevr._bench`)
=================  =============================================================
"""

from __future__ import annotations

from .main import main

__all__ = ["main"]
