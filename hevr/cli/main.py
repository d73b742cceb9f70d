"""The ``hevr`` command line: keygen, convert-key, encrypt, render, recolour, slice, decrypt, info,
upgrade-store, pyramid, demo, bench.

Run ``hevr COMMAND --help`` for each command's options and an example. An error is one line
on stderr, ``hevr: error: --key: expected a private key file, got a public key (key.pub.json)``,
that starts with the option or argument it is about, in the CLI's words (``--key``, ``INPUT``,
``STORE``), never a Python parameter's name; ``--verbose`` adds INFO logging and tracebacks.

Exit status, one rule for every command, applied in :func:`main` only (by error class:
:mod:`hevr.cli.exits`, which also holds each command's Python-name -> option mapping):

* 0 - done (``hevr info``: and every check passed).
* 2 - the command line asks for something that cannot be done as given: argparse's errors,
  bad option values or combinations, a named file that is missing or of the wrong kind (not a
  key, store, frame or volume hevr reads; a public key where the private one is needed), an
  output that exists without ``--force``/``--overwrite``, a key of another volume, a render the
  planner refuses (the message names the option to change). Fix the command line.
* 1 - the data or the run failed: a corrupt, tampered or incomplete store, frame or scan, a failed
  integrity check (``hevr info`` whose check fails too), an I/O failure, a missing optional
  dependency, a memory limit, a crashed worker or any other error.
* 130 - interrupted (Ctrl-C).

Start-up: this module, the parser (:mod:`hevr.cli.parser`) and the exit rule import the standard
library and a few small hevr modules only. The command's arguments are added for the command
being run, and its module is imported when it runs (:func:`main`, through
:data:`hevr.cli.parser.COMMANDS`), so ``hevr --version`` and ``hevr --help`` import neither Dask
nor Zarr nor numpy, and ``hevr info KEY`` only the key code (``tests/cli/test_startup.py``).
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import sys
import traceback
import warnings
from collections.abc import Sequence
from typing import Any, NoReturn, cast

from ..core.lazy import resolve
from .exits import cli_message, exit_code, interrupted_message
from .parser import (
    COMMANDS,
    build_parser,
    command_named,
    join_negative_values,
    requested_command,
    value_options,
)
from .util import err_line, show_warning, silence_stdout

__all__ = ["build_parser", "main", "run"]


def _setup_logging(verbose: bool) -> logging.Handler:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(
        logging.Formatter(
            "hevr: %(levelname)s: %(message)s" if not verbose else "%(asctime)s %(name)s %(levelname)s: %(message)s"
        )
    )
    logger = logging.getLogger("hevr")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO if verbose else logging.WARNING)
    # the progress lines of a job shown off a terminal (only jobs asked to show them: show_progress)
    logging.getLogger("hevr.progress").setLevel(logging.INFO)
    return handler


def _names_as_bytes(stream: Any) -> str | None:
    """Let ``stream`` print a path that is not UTF-8 (argv holds its bytes as surrogate escapes,
    :func:`os.fsdecode`) as those bytes, as ``printf`` would, instead of raising
    ``UnicodeEncodeError``; returns its previous ``errors`` setting (None: left as it was)."""
    old = getattr(stream, "errors", None)
    if old != "strict" or not callable(getattr(stream, "reconfigure", None)):
        return None
    try:
        stream.reconfigure(errors="surrogateescape")
    except (AttributeError, ValueError, OSError):  # pragma: no cover - a stream that cannot change
        return None
    return old


def _run(args: Any) -> int:
    """Run the command ``args`` names: the CLI's one dispatch point. Its module (and with it Dask,
    Zarr, the readers, as it needs) is imported here, now that it is known to be needed."""
    return resolve(command_named(args.command).handler, __package__)(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command ``argv`` (default ``sys.argv[1:]``) and return its exit code (module
    docstring); a program or notebook that calls it keeps running whatever the command did."""
    return _main(argv)


def run() -> int:
    """The ``hevr`` console script and ``python -m hevr``: :func:`main`, and a command interrupted
    with Ctrl-C ends the process as soon as its one line is printed (:func:`_leave`)."""
    code = _main(None)
    if code == 130:
        _leave(code)
    return code


def _leave(code: int) -> NoReturn:
    """End the process now with ``code``, without the interpreter's teardown. After Ctrl-C the
    tasks are stopped, the local workers ended, the store's files closed and the one line printed;
    what is left is Dask's exit handlers and the collection of the heap of Dask, Zarr and numpy:
    0.1-0.2 s of CPU, but 2-5 s on a loaded 2-core machine (issue 49), after the user asked to stop."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a reader gone away
            stream.flush()
    os._exit(code)


def _main(argv: Sequence[str] | None) -> int:
    """:func:`main`'s work: parse, run the command, turn its error into one line and an exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    name = requested_command(argv)
    parser = build_parser({name} if name else ())  # the arguments of the command asked for, only
    argv = join_negative_values(argv, value_options(parser))  # --size -5x-5
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    if args.command is None:
        names = [c.name for c in COMMANDS]
        err_line(f"a command is required: {', '.join(names[:-1])} or {names[-1]} (see 'hevr --help')")
        return 2
    handler = _setup_logging(args.verbose)
    errors = _names_as_bytes(sys.stdout)
    try:
        with warnings.catch_warnings():
            if not args.verbose:
                warnings.simplefilter("ignore", DeprecationWarning)
                warnings.simplefilter("ignore", FutureWarning)
            warnings.showwarning = show_warning
            code = _run(args)
            sys.stdout.flush()  # here, so that a reader gone away (`hevr info … | head -1`) is caught below
            return code
    except KeyboardInterrupt:
        err_line(interrupted_message(args))
        return 130
    except BrokenPipeError:  # the reader of stdout left: stop quietly, as Unix tools do
        silence_stdout()
        return 141  # 128 + SIGPIPE
    except Exception as exc:  # one line; the traceback only with --verbose
        if args.verbose:
            traceback.print_exc()
        err_line(cli_message(exc, args))
        return exit_code(exc, args)
    finally:
        logging.getLogger("hevr").removeHandler(handler)
        logging.getLogger("hevr.progress").setLevel(logging.NOTSET)
        if errors is not None:  # _names_as_bytes changed it: the stream has reconfigure (a text stream's)
            cast(io.TextIOWrapper, sys.stdout).reconfigure(errors=errors)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
