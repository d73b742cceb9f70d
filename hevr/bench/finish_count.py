"""Modular multiplications of a frame's finishing, counted from the plan as the CPU backend
performs them (:meth:`hevr.backends.cpu.CpuBackend.combine` and ``pack``).

Per hit pixel with K stored components, C values and reciprocal R (1 for client finishing):

* combination (server finishing of a vector channel): the 2^K − 1 − K subset products (K <= 8),
  then per output channel with a non-zero column one squaring per bit of the column's largest
  coefficient and one product per bit position where some coefficient has a 1 (Straus);
* packing, per group of L values (Horner from the top): the first value T^R by square and
  multiply (bits(R) − 1 squarings and popcount(R) − 1 products; gmpy2's powmod beyond 6 bits,
  counted the same), every further value b squarings and popcount(R) products, and one product
  for the public offset when it is non-zero.

>>> from types import SimpleNamespace as NS
>>> plan = NS(comb=None, channels_out=1, pack_bits=16, per_pack=2, offset=0, finish="client",
...           reciprocal=lambda ns: [1 if n else 0 for n in ns])
>>> finishing_modmuls(plan, [3, 0, 5])
17
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["finishing_modmuls"]


def _combine_cost(comb: Sequence[Sequence[int]]) -> int:
    K, C = len(comb), len(comb[0])
    cost = (1 << K) - 1 - K if K <= 8 else 0
    for ch in range(C):
        col = [int(row[ch]) for row in comb]
        if not any(col):
            continue
        top = max(col).bit_length()
        cost += top + sum(1 for bit in range(top) if any(e >> bit & 1 for e in col))
    return cost


def finishing_modmuls(plan: Any, n_samples: Sequence[int]) -> int:
    """Modular multiplications (squarings included) of finishing every pixel of ``n_samples``
    under ``plan`` (a :class:`~hevr.rendering.planning.planner.RenderPlan`), one tile holding them all."""
    recips = [int(r) for r in plan.reciprocal(list(n_samples))]
    hits = [r for r in recips if r]
    C = plan.channels_out
    per_pixel = _combine_cost(plan.comb) if plan.comb is not None else 0
    exps = [r for r in hits for _ in range(C)]
    J, b = max(1, plan.per_pack), plan.pack_bits
    total = per_pixel * len(hits)
    for start in range(0, len(exps), J):
        group = exps[start : start + J]
        first = group[-1]
        total += max(first.bit_length() - 1, 0) + max(bin(first).count("1") - 1, 0)
        total += sum(b + bin(r).count("1") for r in group[:-1])
        total += 1 if plan.offset else 0
    return total
