"""What a server with write access to a store can do to it, for the tests of the key holder's checks."""

from __future__ import annotations

import zarr

from hevr.store.metadata import metadata_checksum


def edit_meta(path, change):
    """Change the store's metadata with ``change(dict)`` and recompute its keyless checksum."""
    group = zarr.open_group(str(path), mode="r+")
    d = dict(group.attrs["hevr"])
    change(d)
    d["checksum"] = metadata_checksum(d)
    group.attrs["hevr"] = d
