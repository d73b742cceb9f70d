"""The ``hevr`` command line: one module per concern.

====================  ==========================================================
``main``              the entry point: parse, run the command, one exit-status rule
``parser``            the table of commands and the parser, built per command on demand
``arguments``         keygen, convert-key, info, upgrade-store, bench: their arguments
``owner_arguments``   encrypt, pyramid, demo: their arguments
``render_arguments``  render, recolour, slice, decrypt: theirs
``options``           argparse value types and shared option groups (light)
``render_options``    types and options quoting the render side (presets, views, sizes)
``verify_options``    --key / --verify of render and slice; what decrypt requires a frame to prove
``keys``              keygen, convert-key, reading a ``--key``, ``info KEY``
``encrypt``           ``hevr encrypt`` and ``hevr upgrade-store``
``render``            ``hevr render``; the mode and store checks the render commands share
``decrypt``           ``hevr recolour`` and ``hevr decrypt``
``info``              ``hevr info``: a key file here, everything else to ``describe``
``describe``          what ``hevr info`` says about stores, frames, sums files, scans
``slice``             ``hevr slice``: encrypted planes (axial, coronal, sagittal, oblique)
``pyramid``           ``hevr pyramid``: the encrypted multi-resolution pyramid
``scan``              inputs (``phantom:N``, files, folders) and what they hold
``finish``            where a frame gets its colours: the ``hevr decrypt`` line printed
``storage``           stores, frames and sums on object storage (fsspec URLs)
``cluster``           the Dask client of a command (``--scheduler``, ``--workers``)
``exits``             the exit-status rule and the CLI's words in error messages
``util``              shared checks, messages and formatting (light)
``demo``              ``hevr demo``: the whole data path on a phantom
``demo_jobs``         the demo's figure set: each image rendered, decrypted, compared
``sheet``             the demo's contact sheet
``bench``             ``hevr bench`` (the engine is :mod:`hevr.bench`)
====================  ==========================================================

Start-up: ``main``, ``parser``, ``exits`` and ``util`` import no Dask, Zarr or numpy; a command's
modules are imported when it runs (:mod:`hevr.cli.parser`).
"""

from __future__ import annotations

from .main import main

__all__ = ["main"]
