"""One length unit for the three voxel sizes of microscopy formats (OME-TIFF, OME-Zarr).

OME-TIFF (``PhysicalSizeXUnit`` …) and OME-Zarr (each axis's ``unit``) record one unit per
axis. A z step in millimetres next to x and y steps in micrometres is legal, and taking the
numbers as they are would make the volume 1000 times too thick. :func:`common_unit`
converts the three sizes into the x axis's unit when the units differ (SI and imperial
length units, in the OME and UDUNITS spellings), and refuses units it does not know.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from ..errors import VolumeFormatError

__all__ = ["LENGTH_UNITS", "common_unit"]

_log = logging.getLogger(__name__)

#: Metres per unit, by the spellings OME (symbols) and NGFF (UDUNITS names) use.
LENGTH_UNITS: dict[str, float] = {}
for _names, _metres in (
    ("km kilometer kilometre", 1e3),
    ("m meter metre", 1.0),
    ("cm centimeter centimetre", 1e-2),
    ("mm millimeter millimetre", 1e-3),
    ("µm μm um micrometer micrometre micron", 1e-6),
    ("nm nanometer nanometre", 1e-9),
    ("Å angstrom ångström", 1e-10),
    ("pm picometer picometre", 1e-12),
    ("in inch", 0.0254),
    ("ft foot", 0.3048),
):
    LENGTH_UNITS.update(dict.fromkeys(_names.split(), _metres))


def common_unit(
    name: str, sizes: Sequence[float], units: Sequence[str | None]
) -> tuple[tuple[float, float, float], str | None]:
    """Voxel sizes (x, y, z) in one unit (x's), given each axis's unit (None: not recorded).

    A missing unit is taken to be the others' (logged); two different recorded units are
    converted when both are lengths in :data:`LENGTH_UNITS`, else refused.

    >>> common_unit("a.tif", (0.5, 0.5, 0.002), ("µm", "µm", "mm"))
    ((0.5, 0.5, 2.0), 'µm')
    >>> common_unit("a.zarr", (1, 1, 1), ("micrometer", "micrometer", "parsec"))
    Traceback (most recent call last):
    ...
    hevr.errors.VolumeFormatError: a.zarr: voxel sizes in different units ('micrometer', 'micrometer', 'parsec'); \
expected one unit or known length units (m, cm, mm, µm, nm, ...)
    """
    known = [u for u in units if u]
    out = tuple(float(v) for v in sizes)
    if len(set(known)) <= 1:
        if known and len(known) < len(units):
            _log.warning("%s: some axes record no unit; taking %s for all", name, known[0])
        return out, (known[0] if known else None)  # type: ignore[return-value]
    target = units[0] or known[0]
    if not all(u is None or u in LENGTH_UNITS for u in units):
        raise VolumeFormatError(
            f"{name}: voxel sizes in different units {tuple(units)!r}; expected one unit or "
            "known length units (m, cm, mm, µm, nm, ...)"
        )
    scaled = tuple(v * LENGTH_UNITS[u or target] / LENGTH_UNITS[target] for v, u in zip(out, units))
    _log.info("%s: voxel sizes %s in units %s, converted to %s %s", name, out, tuple(units), scaled, target)
    return scaled, target  # type: ignore[return-value]
