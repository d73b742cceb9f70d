"""``hevr render|slice --server URL NAME_OR_ID``: the key holder's connection to ``hevr serve``.

The options (:func:`hevr.cli.render_options.add_server_option`) are ``--server``, ``--cafile``,
``--timeout`` (each whole exchange: connecting, the answer's head and body, waits for a busy
server; not the decryption here) and ``--connect-timeout``; the token comes from ``HEVR_TOKEN``.
A failure of the server is a typed :class:`hevr.RemoteError` whose one-line message says what to
do where that is known (set ``HEVR_TOKEN``, pass ``--cafile``, use ``https://`` or ``http://``,
a larger ``--timeout``); the command exits 1 for it, as for any failed run.
"""

from __future__ import annotations

import os
from typing import Any

from ..errors import ParameterError
from ..remote.client import connect
from .util import UsageError

__all__ = ["connect_remote", "open_remote"]

_REMOTE_OPTIONS = (
    ("url", "--server"),
    ("token", "HEVR_TOKEN"),
    ("cafile", "--cafile"),
    ("timeout", "--timeout"),
    ("connect_timeout", "--connect-timeout"),
)


def connect_remote(args: Any) -> Any:
    """The :class:`~hevr.remote.client.Server` of ``args.server`` (``--cafile``, ``--timeout``,
    ``--connect-timeout``), the token from ``$HEVR_TOKEN`` (never an argument: the process list
    shows arguments to every user); a refused setting is a :class:`UsageError` naming the option
    or variable (``--timeout: expected seconds in (0, 86400], got -1.0``), as the command line
    says it. ``hevr render|slice --server`` and ``hevr stores`` connect here."""
    try:
        return connect(
            args.server,
            token=os.environ.get("HEVR_TOKEN") or None,
            cafile=args.cafile,
            timeout=args.timeout,
            connect_timeout=args.connect_timeout,
        )
    except ParameterError as exc:  # in the command line's words
        text = str(exc)
        for name, option in _REMOTE_OPTIONS:
            if text.startswith(f"{name}: "):
                raise UsageError(f"{option}: {text[len(name) + 2 :]}") from None
        raise


def open_remote(args: Any) -> Any:
    """The store ``args.store`` (a served name or a store id) on the render server ``args.server``
    (:func:`connect_remote`)."""
    if args.scheduler or args.workers:
        raise UsageError("--server: expected no --scheduler or --workers (the server renders on its own cluster)")
    return connect_remote(args).open(args.store)
