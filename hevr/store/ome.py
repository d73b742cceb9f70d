"""The group's ``ome`` attribute of a store with pyramid levels: OME-Zarr (0.5) ``multiscales``
derived from the checksummed ``hevr`` attribute (docs/format.md, "Pyramid levels").

>>> from types import SimpleNamespace as NS
>>> meta = NS(levels=[NS(level=1, complete=True)], data_channels=("scalar",), spacing=(1.0, 1.0, 2.0))
>>> [d["path"] for d in ome_attribute(meta)["multiscales"][0]["datasets"]]
['scalar', 'levels/1/scalar']
"""

from __future__ import annotations

from typing import Any

__all__ = ["ome_attribute"]


def ome_attribute(meta: Any) -> dict:
    """The group's ``ome`` attribute: OME-Zarr (0.5) ``multiscales``, one per channel, listing
    level 0 and every complete pyramid level with its scale and translation (array order,
    z, y, x; the component and ciphertext-byte axes unscaled). Derived from the checksummed
    ``hevr`` attribute, so it is checked byte for byte on opening; ciphertexts stay opaque to
    OME tools, but the pyramid is discoverable the standard way (not a valid OME-NGFF image: the
    arrays end in the ciphertext-byte axis, docs/format.md)."""
    space = [{"name": a, "type": "space"} for a in ("z", "y", "x")]
    record = [{"name": "ciphertext_byte", "type": "ciphertext"}]
    done = [lv.level for lv in meta.levels if lv.complete]
    out = []
    for ch in meta.data_channels:  # tag channels are not images: not listed
        lead = [{"name": "component", "type": "channel"}] if ch != "scalar" else []
        datasets = []
        for lv in [0] + done:
            scale = [1.0] * len(lead) + [s * 2**lv for s in meta.spacing[::-1]] + [1.0]
            transforms: list[dict] = [{"type": "scale", "scale": scale}]
            if lv:
                shift = [0.0] * len(lead) + [s * (2**lv - 1) / 2 for s in meta.spacing[::-1]] + [0.0]
                transforms.append({"type": "translation", "translation": shift})
            datasets.append({"path": f"levels/{lv}/{ch}" if lv else ch, "coordinateTransformations": transforms})
        out.append({"name": ch, "axes": lead + space + record, "datasets": datasets})
    return {"version": "0.5", "multiscales": out}
