"""Per-process caches of the few most recent keys' derived tables (owner-side fixed-base tables,
tag keys, kernel tables): a dict that keeps the ``size`` most recently added entries, with a lock
for the threads of one worker. Secret-derived values live in process memory only, never longer
than the next few keys.

>>> r = Recent(2)
>>> r.keep(1, "a"), r.keep(2, "b"), r.keep(3, "c"), sorted(r), r.find(1), r.find(3)
('a', 'b', 'c', [2, 3], None, 'c')
"""

from __future__ import annotations

import threading
from typing import Any

__all__ = ["Recent"]


class Recent(dict[Any, Any]):
    """A dict of at most ``size`` entries; :meth:`keep` drops the oldest first."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.size = int(size)
        self.lock = threading.Lock()

    def find(self, key: Any) -> Any:
        """The value kept for ``key``, or None."""
        with self.lock:
            return self.get(key)

    def keep(self, key: Any, value: Any) -> Any:
        """Keep ``value`` for ``key`` (dropping the oldest entries beyond ``size``); returns it."""
        with self.lock:
            self.pop(key, None)
            while len(self) >= self.size:
                self.pop(next(iter(self)))
            self[key] = value
        return value
