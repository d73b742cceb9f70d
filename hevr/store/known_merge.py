"""Merging one name's entries of two known-stores files (:func:`hevr.store.known.import_known_stores`).

The rule: retired ids are unioned; a store retired on either side stays retired (the other side's
current store under the name wins); when neither side retired the other's store, the entry
recorded later wins and the other's store is retired. An unsigned (version-1) entry gives way to
the MAC'd one, its store retired if it is another.

>>> from hevr.store.known_file import KnownStore
>>> a = KnownStore("a" * 16, "d1", True, "fp", "2024-01-01T00:00:00Z")
>>> b = KnownStore("b" * 16, "d2", True, "fp", "2023-01-01T00:00:00Z", retired=("a" * 16,))
>>> winner(a, b) is b, merged_retired(a, b, b)     # b's side retired a: a stays retired
(True, ('aaaaaaaaaaaaaaaa',))
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .known_file import MAX_RETIRED, KnownStore, signed_by

__all__ = ["merge_entry", "merged_retired", "winner"]


def winner(mine: KnownStore, theirs: KnownStore) -> KnownStore:
    """The entry whose store is current under the name after the merge."""
    if mine.store_id == theirs.store_id:
        return theirs if theirs.recorded > mine.recorded and mine.signed else mine if mine.signed else theirs
    if theirs.store_id in mine.retired:
        return mine if mine.signed else theirs
    if mine.store_id in theirs.retired or not mine.signed:
        return theirs
    return theirs if theirs.recorded > mine.recorded else mine


def merged_retired(mine: KnownStore, theirs: KnownStore, win: KnownStore) -> tuple[str, ...]:
    """The union of both sides' retired ids and the losing side's store (not the winner's), newest last."""
    ids = list(mine.retired) + list(theirs.retired) + [mine.store_id, theirs.store_id]
    return tuple(x for x in dict.fromkeys(ids) if x != win.store_id)[-MAX_RETIRED:]


def merge_entry(mine: KnownStore | None, theirs: KnownStore, private_key: Any, name: str) -> KnownStore:
    """The MAC'd entry of ``name`` after merging ``theirs`` (MAC-checked) into ``mine`` (None:
    nothing recorded here); ``mine`` itself when nothing changes."""
    if mine is None:
        return theirs
    win = winner(mine, theirs)
    new = signed_by(private_key, name, dataclasses.replace(win, retired=merged_retired(mine, theirs, win), mac=""))
    return mine if new == mine else new
