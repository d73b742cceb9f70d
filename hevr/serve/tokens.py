"""Bearer tokens of ``hevr serve``: who may render which store, and how many frames at once.

The tokens file (``hevr serve --tokens FILE``) is JSON and holds no token, only its SHA-256, so a
copy of the file (a backup, a container image) grants nothing::

    {"version": 1,
     "tokens": [{"name": "radiology", "sha256": "<64 hex digits>", "stores": ["3f2a…", "*"],
                 "concurrent": 2}]}

``stores`` lists store ids or ``"*"`` (every served store); ``concurrent`` bounds the renders a
token runs at once (default :data:`DEFAULT_CONCURRENT`; more are answered 429 with
``Retry-After``). ``hevr serve --new-token NAME --tokens FILE`` adds a fresh token's entry to the
file (:func:`hevr.serve.token_file.add_token`) and prints the token once.

A running server re-reads its file when it changes (:class:`hevr.serve.token_file.TokenFile`:
rotation and revocation without a restart); a new file that does not parse keeps the previous
table in force, and an empty list revokes every token.

A presented token is hashed and compared with *every* entry in constant time
(:func:`hmac.compare_digest`), so the time of a refusal says nothing about how close a guess was.
Tokens are never logged: the server logs the entry's ``name``.

>>> t = TokenTable.from_dict({"version": 1, "tokens": [{"name": "a", "sha256": hash_token("s3cret"),
...                                                    "stores": ["*"]}]})
>>> t.lookup("s3cret").name, t.lookup("guess")
('a', None)
"""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.files import read_regular
from ..errors import ParameterError
from ..remote.protocol import MAX_BODY, parse_json

__all__ = ["DEFAULT_CONCURRENT", "Token", "TokenTable", "hash_token", "new_token"]

DEFAULT_CONCURRENT = 2
_HEX64 = re.compile(r"[0-9a-f]{64}")
_NAME = re.compile(r"[A-Za-z0-9_.@-]{1,64}")
_STORE = re.compile(r"[0-9a-f]{16}|\*")
MAX_TOKENS = 256  # the file is parsed as one request body is: at most 64 KiB


def hash_token(token: str) -> str:
    """The hex SHA-256 of a token's UTF-8 bytes: what the tokens file holds."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def new_token() -> str:
    """A fresh bearer token: 32 bytes from :mod:`secrets`, URL-safe base64 (43 characters)."""
    return secrets.token_urlsafe(32)


@dataclass(frozen=True)
class Token:
    """One entry of the tokens file (its digest, never the token)."""

    name: str
    digest: bytes
    stores: frozenset
    concurrent: int = DEFAULT_CONCURRENT

    def __repr__(self) -> str:
        return f"Token({self.name!r}, stores={sorted(self.stores)}, concurrent={self.concurrent})"

    def may_render(self, store_id: str) -> bool:
        return "*" in self.stores or store_id in self.stores


@dataclass(frozen=True)
class TokenTable:
    """The parsed tokens file."""

    tokens: tuple

    @classmethod
    def from_dict(cls, d: Any, where: str = "tokens", *, empty: bool = False) -> TokenTable:
        """The table of a parsed tokens file; ``empty``: an empty list too (a running server's
        re-read: every token revoked), else 1 to :data:`MAX_TOKENS` entries."""
        if not isinstance(d, dict) or set(d) != {"version", "tokens"}:
            raise ParameterError(
                f"{where}: expected an object with exactly 'version' and 'tokens', got "
                f"{sorted(d) if isinstance(d, dict) else type(d).__name__}"
            )
        if d["version"] != 1 or type(d["version"]) is not int:
            raise ParameterError(f"{where}: version: expected 1, got {d['version']!r}")
        entries = d["tokens"]
        least = 0 if empty else 1
        if not isinstance(entries, list) or not least <= len(entries) <= MAX_TOKENS:
            got = f"{len(entries)} entries" if isinstance(entries, list) else type(entries).__name__
            hint = " (a server starts with a token at least; emptied under a running server, the file revokes them all)"
            raise ParameterError(
                f"{where}: tokens: expected a list of {least} to {MAX_TOKENS} entries, got {got}"
                + (hint if entries == [] else "")
            )
        out, names, digests = [], set(), set()
        for i, e in enumerate(entries):
            at = f"{where}: tokens[{i}]"
            if not isinstance(e, dict) or not {"name", "sha256", "stores"} <= set(e) <= {
                "name",
                "sha256",
                "stores",
                "concurrent",
            }:
                raise ParameterError(
                    f"{at}: expected the fields name, sha256, stores (and concurrent), got "
                    f"{sorted(e) if isinstance(e, dict) else type(e).__name__}"
                )
            if not isinstance(e["name"], str) or not _NAME.fullmatch(e["name"]) or e["name"] in names:
                raise ParameterError(
                    f"{at}.name: expected a unique name of 1-64 letters, digits or _.@-, got {str(e['name'])[:70]!r}"
                )
            if not isinstance(e["sha256"], str) or not _HEX64.fullmatch(e["sha256"]) or e["sha256"] in digests:
                raise ParameterError(
                    f"{at}.sha256: expected a unique SHA-256 of the token as 64 lower-case hex digits "
                    "(hevr serve --new-token NAME prints one)"
                )
            stores = e["stores"]
            if (
                not isinstance(stores, list)
                or not stores
                or not all(isinstance(s, str) and _STORE.fullmatch(s) for s in stores)
            ):
                raise ParameterError(
                    f"{at}.stores: expected a list of store ids (16 hex digits) or '*', got {str(stores)[:80]!r}"
                )
            conc = e.get("concurrent", DEFAULT_CONCURRENT)
            if type(conc) is not int or not 1 <= conc <= 64:
                raise ParameterError(f"{at}.concurrent: expected an integer in [1, 64], got {str(conc)[:40]!r}")
            names.add(e["name"])
            digests.add(e["sha256"])
            out.append(Token(e["name"], bytes.fromhex(e["sha256"]), frozenset(stores), conc))
        return cls(tuple(out))

    @classmethod
    def load(cls, path: str | Path) -> TokenTable:
        """Read and check a tokens file (a regular file of at most 64 KiB). Who owns it and may
        write it is not checked here: ``hevr serve`` reads its file through
        :class:`hevr.serve.token_file.TokenFile`, which does."""
        raw = read_regular(path, "tokens", "a tokens file (JSON)", limit=MAX_BODY)
        return cls.from_dict(parse_json(raw, f"tokens {path}"), f"tokens {path}")

    def lookup(self, presented: str | None) -> Token | None:
        """The entry of a presented token, or None; every entry is compared, in constant time."""
        if not presented:
            return None
        digest = hashlib.sha256(presented.encode("utf-8", "surrogateescape")).digest()
        found = None
        for t in self.tokens:
            if hmac.compare_digest(digest, t.digest):
                found = t
        return found
