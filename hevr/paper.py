"""The paper's render settings, in one place (Mazza, Patel, Viola, TVCG 2020).

Public constants only — the settings the paper's figures and tables use — shared by the
command line (:mod:`hevr.cli`), the demo, the benchmarks (:mod:`hevr.bench`), the phantom
and the notebooks. The paper's *measured* numbers (Tables 1-3) are in
:mod:`hevr.bench.paper`.

Transfer functions are tuples of ``(normalised density, colour)`` nodes, colours as CSS
names, so they can be passed to :func:`hevr.render` and :func:`hevr.render_plain` as they
are; :func:`tf_text` gives the ``DENSITY:COLOR,...`` form of ``hevr render --tf``.

>>> tf_text(PAPER_TF2)
'0.076:green,0.651:blue,1.0:red'
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "PAPER_TF1",
    "PAPER_TF2",
    "PAPER_DENSITIES",
    "TF_NODES",
    "PAPER_SIZE",
    "PAPER_IMAGE",
    "PAPER_BRICK",
    "tf_text",
]

#: The paper's first transfer function: blue at density 0.279, red at 0.797.
PAPER_TF1 = ((0.279, "blue"), (0.797, "red"))
#: The paper's second transfer function: green 0.076, blue 0.651, red 1.0.
PAPER_TF2 = ((0.076, "green"), (0.651, "blue"), (1.0, "red"))
#: The emphasised densities of the paper's figures, one per object of the phantom
#: (large sphere, small sphere, cube).
PAPER_DENSITIES = (0.331, 0.653, 0.781)
#: The transfer-function nodes of the paper's Fig. 6(d) and Table 3 (4-dim encoding; its
#: "green" is CSS lime, #00ff00); the first k are used for k colours.
TF_NODES = ((0.0, "blue"), (0.293, "yellow"), (0.664, "lime"), (1.0, "purple"))
#: The paper's test case: a 100³ phantom rendered to 150 x 150 pixels, in bricks of 25³.
PAPER_SIZE = 100
PAPER_IMAGE = 150
PAPER_BRICK = 25


def tf_text(nodes: Any) -> str:
    """The command-line form ``DENSITY:COLOR,...`` of nodes whose colours are names.

    Examples
    --------
    >>> tf_text(PAPER_TF1)
    '0.279:blue,0.797:red'
    """
    return ",".join(f"{float(d)!r}:{c}" for d, c in nodes)
