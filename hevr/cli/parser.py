"""The ``hevr`` argument parser: the table of commands, and each command's arguments built on
demand.

Why on demand
-------------
A command's help and checks quote the library (transfer-function presets, views, modalities, the
render pixel limit), and its work needs Dask, Zarr and the readers: about half a second of
imports before anything happens. ``hevr --version`` and ``hevr --help`` need none of it,
``hevr info KEY`` only the key code. So the parser is built in two layers:

* :data:`COMMANDS` names every command with its one-line help (all that ``hevr --help`` lists),
  the function that adds its arguments and the function that runs it, as ``"module:function"``
  strings;
* :func:`build_parser` registers every command and adds the arguments of the requested ones
  only: :func:`hevr.cli.main.main` asks for the command ``argv`` names
  (:func:`requested_command`), so ``hevr render --help`` imports
  :mod:`hevr.cli.render_arguments` and nothing of the other commands.

The handler is imported when the command runs (:func:`hevr.cli.main.main`). Both go through
:func:`hevr.core.lazy.resolve`, the package's one place that imports by name; a test checks that
every string in the table names a function.

This module imports the standard library, :mod:`hevr.paper` and the light CLI helpers only.
"""

from __future__ import annotations

import argparse
import re
import textwrap
from collections.abc import Collection, Sequence
from typing import NamedTuple

from .. import __version__
from ..core.lazy import resolve
from ..paper import PAPER_TF1, tf_text
from .exits import EXIT_RULE
from .util import err_line

__all__ = [
    "COMMANDS",
    "Command",
    "build_parser",
    "command_named",
    "join_negative_values",
    "requested_command",
    "value_options",
    "wrap",
]

_RAW = argparse.RawDescriptionHelpFormatter


class Command(NamedTuple):
    """One ``hevr`` command: its name, its line in ``hevr --help``, and ``"module:function"``
    (relative to :mod:`hevr.cli`) of the function that adds its arguments to its subparser and
    of the function that runs it (``args`` -> exit status)."""

    name: str
    help: str
    arguments: str
    handler: str


COMMANDS: tuple[Command, ...] = (
    Command("keygen", "generate a Paillier key pair", ".arguments:keygen_arguments", ".keys:cmd_keygen"),
    Command(
        "key-policy",
        "show or set a private key's policy (every store of it carries tags)",
        ".arguments:key_policy_arguments",
        ".keys:cmd_key_policy",
    ),
    Command(
        "convert-key",
        "convert a key file between hevr's and python-paillier's (pheutil) formats",
        ".arguments:convert_key_arguments",
        ".keys:cmd_convert_key",
    ),
    Command(
        "encrypt", "encrypt a volume into a Zarr store", ".owner_arguments:encrypt_arguments", ".encrypt:cmd_encrypt"
    ),
    Command(
        "render",
        "render an encrypted volume to an encrypted image (no key needed)",
        ".render_arguments:render_arguments",
        ".render:cmd_render",
    ),
    Command(
        "recolour",
        "re-colour saved ray sums with another density or transfer function (no map step)",
        ".render_arguments:recolour_arguments",
        ".decrypt:cmd_recolour",
    ),
    Command(
        "slice",
        "an encrypted slice (axial, coronal, sagittal, oblique) of an encrypted volume (no key needed)",
        ".render_arguments:slice_arguments",
        ".slice:cmd_slice",
    ),
    Command(
        "decrypt",
        "decrypt an encrypted image to PNG (and colour a client-finished frame)",
        ".render_arguments:decrypt_arguments",
        ".decrypt:cmd_decrypt",
    ),
    Command(
        "info",
        "describe a store, a frame, a key or a volume file; list a DICOM folder's series",
        ".arguments:info_arguments",
        ".info:cmd_info",
    ),
    Command(
        "known",
        "the key holder's known stores: list, export, import (MAC'd under the private key)",
        ".known:known_arguments",
        ".known:cmd_known",
    ),
    Command(
        "upgrade-store",
        "convert a format-1 store (no integrity digests) into a new format-2 store",
        ".arguments:upgrade_store_arguments",
        ".encrypt:cmd_upgrade_store",
    ),
    Command(
        "pyramid",
        "add coarse levels (2x2x2 means) to a store, for quick previews (no key needed)",
        ".owner_arguments:pyramid_arguments",
        ".pyramid:cmd_pyramid",
    ),
    Command(
        "serve",
        "serve encrypted stores to key holders over HTTP(S) (renders on the cluster; no key)",
        ".serve:serve_arguments",
        ".serve:cmd_serve",
    ),
    Command(
        "stores",
        "list the stores a hevr serve serves to your token (name, id, size, packed, verifiable)",
        ".stores:stores_arguments",
        ".stores:cmd_stores",
    ),
    Command(
        "demo",
        "the whole pipeline on the paper's figures, no input needed",
        ".owner_arguments:demo_arguments",
        ".demo:cmd_demo",
    ),
    Command(
        "bench",
        "benchmarks: the paper's Tables 1-3, limits, python-paillier, scaling",
        ".arguments:bench_arguments",
        ".bench:cmd_bench",
    ),
)
_BY_NAME = {c.name: c for c in COMMANDS}

DESCRIPTION = (
    "Privacy-preserving remote volume rendering on Paillier-encrypted volumes (after Mazza, Patel, Viola, TVCG 2020)."
)
EPILOG = (
    "typical session:\n"
    "  hevr keygen --bits 2048 --out key.json             # data owner: key pair\n"
    "  hevr encrypt phantom:64 --key key.json --out vol.zarr --vector-dims 4\n"
    "  hevr render vol.zarr --out frame.hevr --mode tf        # server side: the ray sums, no colours\n"
    f"  hevr decrypt frame.hevr --key key.json --out frame.png --tf '{tf_text(PAPER_TF1)}'\n"
    "                                                     # client: colours it; only the key holder sees it\n"
    "  hevr demo                                          # all of the above on the paper's figures\n"
    "\nsizes are printed in world order, labelled: x×y×z for volumes, W×H for images.\n"
    "\n" + EXIT_RULE
)


def wrap(text: str) -> str:
    """Wrap a description (RawDescriptionHelpFormatter keeps the examples' layout)."""
    return textwrap.fill(text, 88)


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is ONE line on stderr (exit code 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        err_line(f"{message} (see '{self.prog} --help')")
        raise SystemExit(2)


def command_named(name: str) -> Command:
    """The :class:`Command` called ``name`` (a name the parser accepted)."""
    return _BY_NAME[name]


def requested_command(argv: Sequence[object]) -> str | None:
    """The command ``argv`` asks for: its first word that is not an option (``hevr`` itself has
    no option that takes a value), or None. Whether it is a command is the parser's to say.

    >>> requested_command(["-v", "render", "vol.zarr"]), requested_command(["--version"])
    ('render', None)
    """
    return next((str(a) for a in argv if not str(a).startswith("-")), None)


def build_parser(commands: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``hevr`` parser: every command registered, with the arguments, description and
    examples of those in ``commands`` (None: of every command, the whole command line).

    ``hevr --help`` and the "invalid choice" error list every command either way; a command
    whose arguments were not added is only a name, so :func:`hevr.cli.main.main` asks for the
    one it runs (module docstring).
    """
    parser = _Parser(prog="hevr", formatter_class=_RAW, description=wrap(DESCRIPTION), epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"hevr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for c in COMMANDS:
        p = sub.add_parser(c.name, help=c.help, formatter_class=_RAW)
        if commands is None or c.name in commands:
            resolve(c.arguments, __package__)(p)
    return parser


NEGATIVE_VALUE = re.compile(r"^-[\d.]")  # "-5x-5", "-1024,3071", "-.5": a value, never an option name


def value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string of ``parser`` and its subcommands that takes exactly one value."""
    out: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out |= value_options(sub)
        elif action.option_strings and action.nargs is None:
            out.update(action.option_strings)
    return out


def join_negative_values(argv: Sequence[str], options: set[str]) -> list[str]:
    """``--size -5x-5`` → ``--size=-5x-5`` for ``options`` that take a value: argparse reads a
    following token that starts with ``-`` as an option unless it is a plain negative number, and
    would say "expected one argument"; joined, the option's own check names what is wrong.

    >>> join_negative_values(["render", "--size", "-5x-5", "--azimuth", "-30", "-q"], {"--size", "--azimuth"})
    ['render', '--size=-5x-5', '--azimuth=-30', '-q']
    """
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = str(argv[i])
        if a in options and i + 1 < len(argv) and NEGATIVE_VALUE.match(str(argv[i + 1])):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out
