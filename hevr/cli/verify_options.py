"""argparse types and options of the ``hevr`` command line about verification: the key holder's
``--key`` / ``--verify [STORE_ID]`` / ``--no-verify`` of ``render`` and ``slice``, and what
``hevr decrypt`` requires a frame to prove (``--require-verified``, ``--expect-store``,
``--expect-view``, ``--max-age``, ``--moved``, ``--unverified``: :class:`hevr.Expect`).

Light to import (the standard library only); :mod:`hevr.cli.render_arguments` adds them.
"""

from __future__ import annotations

import argparse
import re

__all__ = ["add_require_verified_option", "add_verify_option", "age_type"]


def _store_id(text: str) -> str:
    """``--verify``'s optional STORE_ID: 16 lower-case hex digits (a path there is a mistake: STORE first)."""
    if not re.fullmatch(r"[0-9a-f]{16}", text):
        raise argparse.ArgumentTypeError(
            f"expected a store id of 16 lower-case hex digits (the one 'hevr encrypt "
            f"printed; put STORE before --verify), got {text[:40]!r}"
        )
    return text


def add_verify_option(p: argparse.ArgumentParser) -> None:
    """``--key`` / ``--verify [STORE_ID]`` / ``--no-verify`` of render and slice."""
    p.add_argument(
        "--key",
        metavar="KEY.json",
        help="the private key: this process is then the key holder's, which draws the verification seed "
        "after the frame is rendered, checks the frame (a store encrypted with --verifiable) and "
        "stamps the file so that 'hevr decrypt' knows it was checked; without it the frame is not "
        "verified (the process that renders on the cluster must not draw the seed)",
    )
    p.add_argument(
        "--trust-store",
        action="store_true",
        help="with --key: accept STORE as it is now under its name in your known stores (the owner "
        "re-encrypted or replaced it), where another store or version is otherwise refused",
    )
    p.add_argument(
        "--untagged",
        action="store_true",
        help="with --trust-store: accept a store without tags (made with the public key) although the "
        "key's policy requires tags; its frames are not verified",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--verify",
        nargs="?",
        const=True,
        default=None,
        metavar="STORE_ID",
        type=_store_id,
        help="with --key: require the check against the store's tags (on by default for a verifiable "
        "store): the cluster also sums the tags (about twice the work); with the STORE_ID 'hevr "
        "encrypt' printed, any other store is refused",
    )
    g.add_argument("--no-verify", action="store_true", help="skip the check against the store's tags")


def _view_key(text: str) -> str:
    """``--expect-view``'s KEY: 16 lower-case hex digits (``hevr render`` prints it)."""
    if not re.fullmatch(r"[0-9a-f]{16}", text):
        raise argparse.ArgumentTypeError(
            f"expected a view key of 16 lower-case hex digits (the one 'hevr render' "
            f"printed, or 'hevr info FRAME' shows), got {text[:40]!r}"
        )
    return text


_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400}


def age_type(text: str) -> float:
    """``--max-age``: seconds, or a number with s, m, h or d.

    >>> age_type("90"), age_type("2h"), age_type("7d")
    (90.0, 7200.0, 604800.0)
    """
    m = re.fullmatch(r"(\d+(?:\.\d+)?)([smhd]?)", text.strip())
    if not m or float(m.group(1)) <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive age such as 3600, 90m, 12h or 7d, got {text[:40]!r}")
    return float(m.group(1)) * _UNITS[m.group(2) or "s"]


def add_require_verified_option(p: argparse.ArgumentParser) -> None:
    """``hevr decrypt --require-verified [STORE_ID]`` and what the reader expects of the frame."""
    g = p.add_argument_group("what the frame must prove (hevr.Expect)")
    g.add_argument(
        "--require-verified",
        nargs="?",
        const=True,
        default=None,
        metavar="STORE_ID",
        type=_store_id,
        help="refuse (exit 1) a frame that the key holder did not verify (no check against a store's tags, "
        "or no valid stamp), or that was saved elsewhere (copied or moved here: name its store and view "
        "with --expect-store and --expect-view); with STORE_ID, also one of any other store",
    )
    g.add_argument(
        "--expect-store",
        type=_store_id,
        metavar="STORE_ID",
        help="refuse (exit 1) a frame that is not a verified frame of this store",
    )
    g.add_argument(
        "--expect-view",
        type=_view_key,
        metavar="KEY",
        help="refuse (exit 1) a frame that is not a verified frame of this view (the view key 'hevr render' "
        "printed); with --expect-store, a frame saved elsewhere is accepted for what it proves",
    )
    g.add_argument(
        "--max-age",
        type=age_type,
        metavar="AGE",
        help="refuse (exit 1) a verified frame rendered longer ago than AGE (seconds, or 90m, 12h, 7d)",
    )
    g.add_argument(
        "--moved", action="store_true", help="accept a verified frame that was saved elsewhere (you moved it yourself)"
    )
    g.add_argument(
        "--unverified",
        action="store_true",
        help="decrypt a frame without a verification record although the key's policy requires tags "
        "(an unverified image, asked for by name)",
    )
