"""Value ranges and transfer-function presets that depend on the modality only.

Why the modality, and never the data
------------------------------------
A store's ``value_range`` (raw value -> density ``(v - lo)/(hi - lo)``) is public metadata.
A range computed from the voxels (their min/max or percentiles) would tell the server
something about the plaintext, so hevr's defaults never are: an integer volume gets its
dtype's range, and a scan whose header names its modality gets that modality's fixed range
from :data:`MODALITY_RANGES`. The owner may still look at the data locally:
:func:`range_hint` turns the data's min/max into a one-line suggestion that is printed or
logged, never stored.

The ranges
----------
=========  ===============  ===========================================================
CT         (-1024, 3071)    Hounsfield units of 12-bit CT (air -1000, water 0, dense
                            bone ~ +2000, metal clips at 3071). Values below -1024 (the
                            -2048/-3024 padding outside the field of view) clip to
                            density 0, where air already is.
MR         (0, 4095)        MR intensities have no physical unit: their scale depends on
                            the scanner, coil, sequence and reconstruction. Most scanners
                            store 12 bits (DICOM BitsStored 12), so (0, 4095) is the
                            range a stored MR value can take there; larger values (some
                            vendors use the full 16 bits) clip to 1 and :func:`range_hint`
                            says so. For MR this is a container range, not a tissue scale.
US         (0, 255)         B-mode ultrasound is 8-bit grey.
=========  ===============  ===========================================================

No fixed range (:data:`UNSUPPORTED`, :func:`modality_range` raises and names the reason):
PT and NM measure activity (Bq/ml, counts, SUV) whose scale depends on dose, timing and
patient; CR, DX, MG, XA, RF and others are projection radiographs (2-D images; their bit
depth is the detector's). Give those a ``value_range`` (CLI ``--value-range LO,HI``).

Transfer-function presets
-------------------------
A preset is a radiology window (level ``L`` = centre, width ``W``, in the modality's units)
and a few coloured nodes inside it, converted to hevr's normalised densities for a store's
``value_range`` by :func:`tf_preset` (node value ``v`` -> ``(v - lo)/(hi - lo)``, rounded to
4 decimals). hevr's ``tf`` mode sums, per sample, ``dot(e(d), e(d_i)) * c_i`` over the nodes
(paper Alg. 4 encoding): each node lights up densities near ``d_i``, within about
``1/(vector_dims - 1)``, so with the paper's 4 dimensions neighbouring tissues blur into each
other; more dimensions (``--vector-dims 8`` or more) make a preset more selective.

================  ============  ====================================================
ct-bone           W 2000/L 500  nodes at 300, 700, 1500 HU: cancellous to cortical bone
ct-soft-tissue    W 400/L 40    nodes at -100 (fat), 40 (muscle, organs), 200 (contrast)
ct-lung           W 1500/L -600 nodes at -850 (aerated lung), -500 (dense lung), 40 (vessels)
mr-generic        relative      nodes at 15, 40 and 75 % of the value range (no MR unit)
================  ============  ====================================================

Nodes whose value lies outside the value range are left out; a preset none of whose nodes
lie inside it is refused (a CT preset on a store normalised over (0, 255) means nothing).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

from ..core.voxels import check_value_range
from ..errors import ParameterError

__all__ = [
    "MODALITY_RANGES",
    "UNSUPPORTED",
    "TF_PRESETS",
    "TFPreset",
    "HINT_FRACTION",
    "modality_range",
    "normalize_modality",
    "tf_preset",
    "window_density",
    "range_hint",
]

_log = logging.getLogger(__name__)

#: Fixed value range per modality code (module docstring).
MODALITY_RANGES: dict[str, tuple[float, float]] = {
    "CT": (-1024.0, 3071.0),
    "MR": (0.0, 4095.0),
    "US": (0.0, 255.0),
}

#: Modalities with no fixed range, and why.
UNSUPPORTED: dict[str, str] = {
    "PT": "PET activity (Bq/ml, SUV) has no fixed range: it depends on dose, timing and patient",
    "NM": "nuclear-medicine counts have no fixed range: they depend on dose and acquisition time",
    "CR": "computed radiography is a 2-D projection image with the detector's own bit depth",
    "DX": "digital radiography is a 2-D projection image with the detector's own bit depth",
    "MG": "mammography is a 2-D projection image with the detector's own bit depth",
    "XA": "X-ray angiography is a projection image with the detector's own bit depth",
    "RF": "radio fluoroscopy is a projection image with the detector's own bit depth",
}

#: :func:`range_hint` speaks up when the data cover less than this fraction of the range.
HINT_FRACTION = 0.10


def normalize_modality(modality: Any) -> str:
    """A modality code as DICOM spells it (upper case, no blanks).

    >>> normalize_modality(" ct ")
    'CT'
    """
    if not isinstance(modality, str) or not modality.strip():
        raise ParameterError(f"modality: expected a modality code such as 'CT' or 'MR', got {modality!r}")
    return modality.strip().upper()


def modality_range(modality: str) -> tuple[float, float]:
    """The fixed value range of ``modality`` (:data:`MODALITY_RANGES`).

    Examples
    --------
    >>> modality_range("CT")
    (-1024.0, 3071.0)
    >>> modality_range("mr")
    (0.0, 4095.0)
    >>> modality_range("PT")  # doctest: +NORMALIZE_WHITESPACE
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: modality: PT has no fixed value range (PET activity (Bq/ml, SUV) has no fixed
    range: it depends on dose, timing and patient); give a value_range
    """
    code = normalize_modality(modality)
    if code in MODALITY_RANGES:
        return MODALITY_RANGES[code]
    if code in UNSUPPORTED:
        raise ParameterError(f"modality: {code} has no fixed value range ({UNSUPPORTED[code]}); give a value_range")
    raise ParameterError(f"modality: expected one of {', '.join(MODALITY_RANGES)}, got {modality!r}")


@dataclass(frozen=True)
class TFPreset:
    """A transfer-function preset: a window and its nodes in the modality's units.

    Attributes
    ----------
    modality : str
        The modality the values are in (``"CT"``: Hounsfield units).
    center, width : float
        The radiology window (level, width); for a ``relative`` preset, fractions of the range.
    nodes : tuple of (value, "#rrggbb")
        Node values inside the window and their colours.
    relative : bool
        Values are fractions of the value range (MR: no physical unit), not absolute values.
    description : str
        One line for listings.
    """

    modality: str
    center: float
    width: float
    nodes: tuple[tuple[float, str], ...]
    relative: bool = False
    description: str = ""


#: The presets by name (module docstring).
TF_PRESETS: dict[str, TFPreset] = {
    "ct-bone": TFPreset(
        "CT",
        500.0,
        2000.0,
        ((300.0, "#d9b38c"), (700.0, "#f2e6d0"), (1500.0, "#ffffff")),
        description="CT bone window (W 2000 / L 500): bone >= ~300 HU, tan to white",
    ),
    "ct-soft-tissue": TFPreset(
        "CT",
        40.0,
        400.0,
        ((-100.0, "#e6c86e"), (40.0, "#c0504d"), (200.0, "#ffd8d0")),
        description="CT soft-tissue window (W 400 / L 40): fat yellow, muscle red",
    ),
    "ct-lung": TFPreset(
        "CT",
        -600.0,
        1500.0,
        ((-850.0, "#5b8fd9"), (-500.0, "#a8c8ff"), (40.0, "#ff9090")),
        description="CT lung window (W 1500 / L -600): lung blue, vessels pink",
    ),
    "mr-generic": TFPreset(
        "MR",
        0.45,
        0.9,
        ((0.15, "#404080"), (0.40, "#b0b0b0"), (0.75, "#ffffff")),
        relative=True,
        description="MR, relative to the value range: dark blue to white",
    ),
}


def _rgb(hex_colour: str) -> tuple[float, float, float]:
    return tuple(int(hex_colour[i : i + 2], 16) / 255 for i in (1, 3, 5))  # type: ignore[return-value]


def window_density(center: float, width: float, value_range: Any) -> tuple[float, float]:
    """The densities ``(lo, hi)`` of the window ``[center - width/2, center + width/2]``, clipped to [0, 1].

    Examples
    --------
    >>> window_density(40, 400, (-1024, 3071))          # CT soft tissue
    (0.211, 0.3087)
    >>> window_density(500, 2000, (-1024, 3071))        # CT bone
    (0.128, 0.6164)
    """
    lo, hi = check_value_range(value_range)
    c = float(center)
    w = float(width)
    if not (math.isfinite(c) and math.isfinite(w) and w > 0):
        raise ParameterError(f"width: expected a finite positive window (centre, width), got ({center!r}, {width!r})")
    span = hi - lo
    a = min(1.0, max(0.0, (c - w / 2 - lo) / span))
    b = min(1.0, max(0.0, (c + w / 2 - lo) / span))
    return round(a, 4), round(b, 4)


def tf_preset(name: str, value_range: Any) -> list[tuple[float, tuple[float, float, float]]]:
    """The nodes of preset ``name`` as hevr's ``nodes=`` for a store normalised over ``value_range``.

    Parameters
    ----------
    name : str
        A key of :data:`TF_PRESETS` (``"ct-bone"``, ``"ct-soft-tissue"``, ``"ct-lung"``, ``"mr-generic"``).
    value_range : (lo, hi)
        The store's value range (``ev.value_range``).

    Returns
    -------
    list of (density, (r, g, b))
        Densities in [0, 1] (4 decimals, distinct), colours in [0, 1].

    Examples
    --------
    >>> [d for d, _ in tf_preset("ct-bone", (-1024, 3071))]
    [0.3233, 0.421, 0.6164]
    >>> tf_preset("mr-generic", (0, 4095))[0]
    (0.15, (0.25098039215686274, 0.25098039215686274, 0.5019607843137255))
    """
    if name not in TF_PRESETS:
        raise ParameterError(f"name: expected a transfer-function preset ({', '.join(TF_PRESETS)}), got {name!r}")
    preset = TF_PRESETS[name]
    lo, hi = check_value_range(value_range)
    nodes: list[tuple[float, tuple[float, float, float]]] = []
    for value, colour in preset.nodes:
        d = value if preset.relative else (value - lo) / (hi - lo)
        if not 0.0 <= d <= 1.0:
            _log.info("preset %s: node at %g lies outside the value range (%g, %g); left out", name, value, lo, hi)
            continue
        d = round(d, 4)
        if all(d != other for other, _ in nodes):
            nodes.append((d, _rgb(colour)))
    if not nodes:
        raise ParameterError(
            f"name: the {preset.modality} preset {name!r} has no node inside the value range "
            f"({lo:g}, {hi:g}) (its nodes are at {', '.join(f'{v:g}' for v, _ in preset.nodes)}); "
            "was the volume encrypted with its modality's range?"
        )
    return nodes


def range_hint(data_lo: float, data_hi: float, value_range: Any) -> str | None:
    """A one-line suggestion when the data use the value range badly, else ``None``.

    The data's own min/max are the owner's to look at: the hint is printed or logged, never
    stored. It speaks up when the data cover less than :data:`HINT_FRACTION` of the range
    (every voxel gets nearly the same density: a flat render) or reach above its top (those
    voxels all get density 1). Values below the range are not mentioned: they are usually
    padding outside the field of view (CT's -2048 or -3024), which density 0 suits.

    Examples
    --------
    >>> range_hint(-1000, 2000, (-1024, 3071)) is None
    True
    >>> print(range_hint(0, 1500, (-32768, 32767)))  # doctest: +NORMALIZE_WHITESPACE
    the data span 0 .. 1500, only 2.3 % of the value range (-32768, 32767): the render will look nearly flat; set
    the modality (--modality CT|MR) or the value range (--value-range LO,HI)
    """
    lo, hi = check_value_range(value_range)
    dlo, dhi = float(data_lo), float(data_hi)
    if not (math.isfinite(dlo) and math.isfinite(dhi)) or dhi < dlo:
        return None
    fix = "set the modality (--modality CT|MR) or the value range (--value-range LO,HI)"
    covered = max(0.0, min(hi, dhi) - max(lo, dlo)) / (hi - lo)
    if covered < HINT_FRACTION:
        return (
            f"the data span {dlo:g} .. {dhi:g}, only {100 * covered:.2g} % of the value range ({lo:g}, {hi:g}): "
            f"the render will look nearly flat; {fix}"
        )
    if dhi > hi:
        return (
            f"the data reach {dhi:g}, above the value range ({lo:g}, {hi:g}): every value above {hi:g} gets "
            f"density 1; {fix}"
        )
    return None
