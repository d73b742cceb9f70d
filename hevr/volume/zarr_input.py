"""Plaintext Zarr inputs: a Zarr v2/v3 array, or an OME-Zarr (NGFF 0.4/0.5) multiscale image.

* A folder holding one array (``zarr.json`` with ``node_type: array``, or ``.zarray``) must
  be 3-D, (z, y, x) with x fastest, spacing (1, 1, 1).
* An OME-Zarr image is a group whose attributes hold ``multiscales`` (NGFF 0.4, Zarr v2)
  or ``ome.multiscales`` (NGFF 0.5, Zarr v3). hevr reads its first dataset (the full
  resolution). The axes (``t``, ``c``, ``z``, ``y``, ``x``, by name and type) decide what
  is kept: the three ``space`` axes, ordered (z, y, x) by name; a ``time`` axis of more
  than one point needs ``volume=i``; a ``channel`` axis of more than one channel is refused
  (hevr encrypts one scalar per voxel); other axes of size 1 are dropped. The spacing is the
  product of the dataset's and the multiscale's ``scale`` transformations on x, y, z, in
  the axes' ``unit`` (``details["unit"]``; sizes in different length units are converted to
x's, :mod:`hevr.volume._units`), the origin their ``translation``. A ``scale`` or
``translation`` that is not one number per axis is refused, not ignored. NGFF records
  no patient orientation: ``frame`` is None.
* An encrypted hevr store (a group whose attributes hold ``hevr``, or any array inside one)
  is refused: it holds ciphertexts, not a plaintext volume (open it with
  :func:`hevr.open_volume`).

The result is a numpy array read fully into memory (Zarr chunks are compressed and cannot
be memory-mapped); only the chosen time point is read, and only when its declared size fits
in this machine's memory (zarr fills missing chunks, so a tiny store may declare terabytes).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..errors import HevrError, VolumeFormatError
from ._memory import check_fits
from ._select import reject_index, select_index
from ._units import common_unit
from .scan import Scan

__all__ = ["read_zarr", "is_zarr"]

_log = logging.getLogger(__name__)

_META = ("zarr.json", ".zarray", ".zgroup")
_MAX_META_BYTES = 1 << 20


def is_zarr(path: Path) -> bool:
    """Whether the folder ``path`` is a Zarr array or group (v2 or v3)."""
    return any((path / name).is_file() for name in _META)


def _attributes(folder: Path) -> dict[str, Any]:
    """The attributes of the Zarr node in ``folder`` ({} when none or unreadable)."""
    for name, key in (("zarr.json", "attributes"), (".zattrs", None)):
        f = folder / name
        try:
            if not f.is_file() or f.stat().st_size > _MAX_META_BYTES:
                continue
            doc = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        attrs = doc.get(key, {}) if key else doc
        if isinstance(attrs, dict) and attrs:
            return attrs
    return {}


def _refuse_hevr_store(path: Path) -> None:
    for folder in (path, *list(path.resolve().parents)[:4]):
        if "hevr" in _attributes(folder):
            where = "" if folder == path else f" (inside {folder.name})"
            raise VolumeFormatError(
                f"{path.name}: this is an encrypted hevr store{where}, not a plaintext "
                "volume; open it with hevr.open_volume or render it with hevr render"
            )


def _multiscale(attrs: dict[str, Any]) -> dict[str, Any] | None:
    ms = attrs.get("multiscales") or (attrs.get("ome") or {}).get("multiscales")
    return ms[0] if isinstance(ms, list) and ms and isinstance(ms[0], dict) else None


def _transform(path: Path, items: Any, kind: str, n: int) -> np.ndarray:
    """The ``scale``/``translation`` vector of a coordinateTransformations list (1s/0s when absent).

    A transformation of that type whose vector is not ``n`` numbers is refused: ignoring it
    would silently give the wrong voxel size.
    """
    for t in items if isinstance(items, list) else []:
        if isinstance(t, dict) and t.get("type") == kind:
            values = t.get(kind)
            if not (
                isinstance(values, list)
                and len(values) == n
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
            ):
                raise VolumeFormatError(
                    f"{path.name}: OME-Zarr {kind}: expected {n} numbers (one per axis), got {str(values)[:80]}"
                )
            return np.array(values, np.float64)
    return np.full(n, 1.0 if kind == "scale" else 0.0)


def _ome(path: Path, group: Any, ms: dict[str, Any], volume: int | None) -> Scan:
    datasets = ms.get("datasets") or []
    if not datasets or not isinstance(datasets[0], dict) or "path" not in datasets[0]:
        raise VolumeFormatError(
            f"{path.name}: OME-Zarr multiscales: expected a list of datasets with a 'path', got {datasets!r}"[:300]
        )
    arr = group[str(datasets[0]["path"])]
    n = arr.ndim
    given = ms.get("axes") or ["t", "c", "z", "y", "x"][-n:]
    axes: list[dict[str, Any]] = [a if isinstance(a, dict) else {"name": str(a)} for a in given]
    if len(axes) != n:
        raise VolumeFormatError(
            f"{path.name}: OME-Zarr axes {[a.get('name') for a in axes]} do not match the "
            f"dataset's {n} dimensions {arr.shape}"
        )
    scale = _transform(path, datasets[0].get("coordinateTransformations"), "scale", n)
    scale = scale * _transform(path, ms.get("coordinateTransformations"), "scale", n)
    shift = _transform(path, datasets[0].get("coordinateTransformations"), "translation", n)
    index: list[Any] = []
    space: list[int] = []
    details: dict[str, Any] = {"axes": [a.get("name") for a in axes], "dataset": str(datasets[0]["path"])}
    for i, (ax, size) in enumerate(zip(axes, arr.shape)):
        name, kind = str(ax.get("name", "")).lower(), ax.get("type", "")
        kind = kind or {"t": "time", "c": "channel", "x": "space", "y": "space", "z": "space"}.get(name, "")
        if kind == "space":
            index.append(slice(None))
            space.append(i)
        elif kind == "channel" and size > 1:
            raise VolumeFormatError(
                f"{path.name}: expected one channel, got {size} along axis {name!r}; hevr "
                "encrypts one scalar per voxel: pick or combine a channel first"
            )
        elif kind == "time" and size > 1:
            picked = select_index(volume, size, path, "time points", f"its axis {name!r}")
            index.append(picked)
            details.update(volume=picked, volumes=size)
        elif size == 1:
            index.append(0)
        else:
            raise VolumeFormatError(
                f"{path.name}: OME-Zarr axis {name!r} (type {kind or 'unknown'}) has {size} "
                "entries; expected time, channel or space axes"
            )
    if "volume" not in details:
        reject_index(volume, path)
    if len(space) != 3:
        raise VolumeFormatError(f"{path.name}: expected 3 space axes (z, y, x), got {len(space)} in {details['axes']}")
    names = [str(axes[i].get("name", "")).lower() for i in space]
    order = [names.index(a) for a in "zyx"] if sorted(names) == ["x", "y", "z"] else [0, 1, 2]
    zyx = [space[o] for o in order]
    units = [axes[zyx[2 - w]].get("unit") for w in range(3)]
    spacing, details["unit"] = common_unit(
        path.name, [float(scale[zyx[2 - w]]) for w in range(3)], [str(u) if u else None for u in units]
    )
    check_fits(path.name, [arr.shape[i] for i in space], arr.dtype, "Zarr data")
    vol = np.asarray(arr[tuple(index)]).transpose(order)
    origin = tuple(float(shift[zyx[2 - w]]) for w in range(3))
    if not all(math.isfinite(v) for v in origin):
        origin = (0.0, 0.0, 0.0)
    return Scan(vol, spacing, origin, None, None, str(path), details)  # type: ignore[arg-type]


def read_zarr(path: Path, *, volume: int | None = None) -> Scan:
    """Read a plaintext Zarr array or OME-Zarr image into a :class:`Scan` (a numpy array, read fully)."""
    _refuse_hevr_store(path)
    try:
        node = zarr.open(store=str(path), mode="r")
        if isinstance(node, zarr.Array):
            reject_index(volume, path)
            if node.ndim != 3:
                raise VolumeFormatError(f"{path.name}: expected a 3-D Zarr array (z, y, x), got shape {node.shape}")
            check_fits(path.name, node.shape, node.dtype, "Zarr data")
            return Scan(
                np.asarray(node[...]),
                (1.0, 1.0, 1.0),
                (0.0, 0.0, 0.0),
                None,
                None,
                str(path),
                {"zarr_format": node.metadata.zarr_format},
            )
        ms = _multiscale(dict(node.attrs))
        if ms is None:
            raise VolumeFormatError(
                f"{path.name}: a Zarr group without OME-NGFF 'multiscales' metadata; "
                "expected an OME-Zarr image or the path of one 3-D array"
            )
        return _ome(path, node, ms, volume)
    except HevrError:
        raise
    except Exception as exc:  # zarr raises many types for broken stores
        raise VolumeFormatError(f"{path.name}: cannot read the Zarr store ({type(exc).__name__}: {exc})") from None
