"""The kernel backends' data: limb batches, Montgomery constants, and the tables the kernels read.

Everything here is shared by every launcher (the host build through ctypes, CuPy on a GPU): it is
plain numpy, computed once per brick, tile or modulus, never once per product.

A batch (:class:`LimbBatch`) is an ``(m, NL)`` array of little-endian 32-bit limbs, either the
values themselves ("normal form", what :meth:`~hevr.backends.base.Backend.from_bytes` makes: the
byte records carry no modulus) or their Montgomery form ``x·R mod N``, ``R = 2^(32·NL)``, for the
modulus ``N`` it records. The first operation that knows ``N`` (a ray product, a merge, ...) turns a
normal batch into Montgomery form in place, once — a resident brick is converted on its first frame
— and every result stays in Montgomery form until :meth:`to_bytes`.

Montgomery constants of an odd ``N`` of ``NL`` limbs (:class:`Modulus`): ``ninv = −N^-1 mod 2^32``,
``R² mod N`` (to Montgomery form: one CIOS product), ``R mod N`` (the form of 1) and 1 (back to
normal form: one CIOS product).

>>> m = Modulus(3 * 2**64 + 1)
>>> m.nl, from_limbs(m.one[None])[0] == 2**96 % m.n
(3, True)
>>> exponent_words([5, 2**40]).tolist()
[[5, 0], [0, 256]]
"""

from __future__ import annotations

import array
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...errors import ParameterError
from ..base import HORNER, SHARED, SINGLE, SQR_COST, ProductPlan
from .host import from_limbs, montgomery_params, to_limbs

__all__ = ["MAX_BUCKETS", "LimbBatch", "Modulus", "PlanTables", "exponent_words", "fold_table", "plan_tables"]

MAX_BUCKETS = 1 << 20  # per task: far beyond any plan the planner makes (w <= 16); larger plans run on gmpy2


class Modulus:
    """Montgomery constants of one odd modulus (limb arrays of ``nl`` limbs, read by the kernels).

    Attributes
    ----------
    n : int
        The modulus.
    nl, ninv : int
        Limbs and ``−n^-1 mod 2^32``.
    limbs, r2, one, unit : numpy.ndarray
        ``n``, ``R² mod n``, ``R mod n`` (1 in Montgomery form) and 1, each ``(nl,)`` uint32.
    """

    __slots__ = ("limbs", "n", "ninv", "nl", "one", "r2", "unit")

    def __init__(self, n: int) -> None:
        self.n = int(n)
        self.nl, self.ninv, r2 = montgomery_params(self.n)
        self.limbs, self.r2, self.one, self.unit = to_limbs([self.n, r2, (1 << (32 * self.nl)) % self.n, 1], self.nl)

    def __repr__(self) -> str:
        return f"Modulus({self.n.bit_length()} bits, {self.nl} limbs)"


class LimbBatch:
    """A batch of residues: ``(m, nl)`` uint32 limbs, in normal form or in Montgomery form mod ``modulus``.

    Opaque to callers (``len()`` only, as every backend's batch). Its state is one tuple, replaced
    whole, so a worker's threads sharing a resident batch see either form, never half of one.
    A batch made by :meth:`joined` holds its parts until the backend first needs its limbs: it then
    converts the parts (in place: resident bricks keep their Montgomery form for the next frame)
    and joins them. The limbs are the launcher's arrays: numpy on the host, device arrays for the
    ``cuda`` backend (a resident brick stays on the GPU between frames); a pickled batch carries
    numpy limbs wherever they lived, so any process can load it (a device launcher uploads them
    on first use).

    >>> b = LimbBatch(np.zeros((3, 2), np.uint32))
    >>> len(b), b.nl, b.modulus is None
    (3, 2, True)
    >>> j = LimbBatch.joined([b, LimbBatch(np.ones((1, 1), np.uint32))])
    >>> len(j), j.limbs.tolist()[2:]
    (4, [[0, 0], [1, 0]])
    """

    __slots__ = ("_parts", "_state")

    def __init__(self, limbs: np.ndarray, modulus: int | None = None) -> None:
        self._state = (limbs, modulus)
        self._parts: tuple[LimbBatch, ...] | None = None

    @classmethod
    def joined(cls, parts: Sequence[LimbBatch]) -> LimbBatch:
        """The concatenation of ``parts`` (normal form), joined when first used."""
        out = cls(np.zeros((0, 1), np.uint32))
        out._parts = tuple(parts)
        return out

    @property
    def parts(self) -> tuple[LimbBatch, ...] | None:
        """The parts of a batch not joined yet, else None."""
        return self._parts

    @property
    def state(self) -> tuple[np.ndarray, int | None]:
        """``(limbs, modulus)``; a batch of parts not joined yet: their normal-form join, not kept."""
        parts = self._parts
        if parts is not None:
            if any(p.modulus is not None for p in parts):  # pragma: no cover - the backend joins those
                raise ParameterError("batch: parts in Montgomery form are joined by the backend")
            rows = [_host(p.state[0]) for p in parts]
            nl = max((r.shape[1] for r in rows), default=1)
            return np.concatenate(
                [np.pad(r, ((0, 0), (0, nl - r.shape[1]))) for r in rows] or [np.zeros((0, 1), np.uint32)]
            ), None
        return self._state

    @state.setter
    def state(self, value: tuple[np.ndarray, int | None]) -> None:
        self._state = value
        self._parts = None  # after the state: a thread that sees no parts sees the joined state

    @property
    def limbs(self) -> np.ndarray:
        return self.state[0]

    @property
    def modulus(self) -> int | None:
        """None in normal form, else the modulus of the Montgomery form."""
        return self.state[1]

    @property
    def nl(self) -> int:
        parts = self._parts
        if parts is not None:
            return max((p.nl for p in parts), default=1)
        return int(self._state[0].shape[1])

    def __len__(self) -> int:
        parts = self._parts
        if parts is not None:
            return sum(len(p) for p in parts)
        return int(self._state[0].shape[0])

    def __getstate__(self):
        limbs, mod = self._state
        return (_host(limbs), mod), self._parts

    def __setstate__(self, state) -> None:
        self._state, self._parts = state

    def __repr__(self) -> str:
        if self._parts is not None:
            return f"LimbBatch({len(self)} values in {len(self._parts)} parts, not joined)"
        limbs, mod = self._state
        form = "normal form" if mod is None else f"Montgomery form mod a {int(mod).bit_length()}-bit modulus"
        return f"LimbBatch({limbs.shape[0]} values, {limbs.shape[1]} limbs, {form})"


def _host(limbs) -> np.ndarray:
    """numpy limbs of a numpy or device (CuPy) array: a device array is downloaded.

    >>> _host(np.ones((1, 1), np.uint32)).tolist()
    [[1]]
    """
    return limbs if isinstance(limbs, np.ndarray) else limbs.get()


def exponent_words(values: Sequence[int] | np.ndarray, name: str = "exps") -> np.ndarray:
    """Non-negative integers as an ``(m, ew)`` uint32 array of little-endian words (``ew >= 2``):
    vectorised below 2^64, word by word beyond.

    >>> exponent_words(np.array([1, 3], np.int64)).tolist()
    [[1, 0], [3, 0]]
    >>> exponent_words([2**64]).shape
    (1, 3)
    """
    arr = values if isinstance(values, np.ndarray) else None
    if arr is not None and arr.dtype.kind in "iu":
        if arr.size and arr.dtype.kind == "i" and arr.min() < 0:
            raise ParameterError(f"{name}: expected non-negative integers, got a negative one")
        return np.ascontiguousarray(arr.astype("<u8").reshape(-1)).view("<u4").reshape(-1, 2)
    try:
        a = np.asarray(values, dtype="<u8").reshape(-1)
        return np.ascontiguousarray(a).view("<u4").reshape(-1, 2)
    except (OverflowError, TypeError, ValueError):
        pass
    ints = [int(v) for v in values]
    if any(v < 0 for v in ints):
        raise ParameterError(f"{name}: expected non-negative integers, got a negative one")
    ew = max(2, -(-max(v.bit_length() for v in ints) // 32))
    return to_limbs(ints, ew)


def fold_table() -> np.ndarray:
    """``fold_min[w]``: the smallest integer above ``2^w − w·S`` (cpu.py's fold rule ``top > fold``
    in integers, so the kernels compare no floats), for ``w < 64``.

    >>> fold_table()[:6].tolist()
    [2, 2, 3, 6, 13, 28]
    """
    return np.array([min(math.floor((1 << w) - w * SQR_COST) + 1, 1 << 62) for w in range(64)], dtype=np.int64)


FOLD = fold_table()


@dataclass
class PlanTables:
    """A :class:`~hevr.backends.base.ProductPlan` as the arrays the ray kernels read.

    Attributes
    ----------
    vl, wl : numpy.ndarray
        Voxels (int64) and weights (uint64) of the pairs.
    tasks : numpy.ndarray
        ``(T, 5)`` int64: kind, start, stop, w, J.
    rep : numpy.ndarray
        Per row its task, -1 for an empty row.
    pre_v, pre_j, pre_start : numpy.ndarray
        Voxels needing shared-bucket powers, their power counts and first row in the powers array.
    pw_off, pw_n : numpy.ndarray
        Per voxel its first row of powers (-1: none) and how many.
    pw_rows, slot : int
        Rows of the powers array; buckets one task needs (the largest of all tasks).
    squarings_pre, duplicate_rows, precomputed, powmod : int
        The :class:`~hevr.backends.base.OpCounter` entries that do not depend on the ciphertexts.
    """

    vl: np.ndarray
    wl: np.ndarray
    tasks: np.ndarray
    rep: np.ndarray
    pre_v: np.ndarray
    pre_j: np.ndarray
    pre_start: np.ndarray
    pw_off: np.ndarray
    pw_n: np.ndarray
    pw_rows: int
    slot: int
    squarings_pre: int
    duplicate_rows: int
    precomputed: int
    powmod: int


def plan_tables(plan: ProductPlan, n_vox: int) -> PlanTables | None:
    """The plan's arrays, checked so that no kernel reads outside them; None when one task would
    need more than :data:`MAX_BUCKETS` buckets (the caller runs such a plan on gmpy2).

    >>> from hevr.backends.base import ONES
    >>> t = plan_tables(ProductPlan(2, 2, [0, -1], [0, 1], [1, 1], [(ONES, 0, 2, 0, 0)]), 2)
    >>> t.tasks.tolist(), t.rep.tolist(), t.slot
    ([[0, 0, 2, 0, 0]], [0, -1], 1)
    """
    vl, wl = _ints(plan.vl, "q"), _ints(plan.wl, "Q")
    cols = list(zip(*plan.tasks)) if isinstance(plan.tasks, list) else None  # columns convert faster than tuples
    tasks = np.array(cols, np.int64).T if cols else np.asarray(plan.tasks, np.int64)
    tasks = np.ascontiguousarray(tasks.reshape(-1, 5))
    rep = np.asarray(plan.rep, dtype=np.int64).reshape(-1)
    n_pairs, n_tasks = vl.size, tasks.shape[0]
    if wl.size != n_pairs or (n_pairs and (vl.min() < 0 or vl.max() >= n_vox)):
        raise ParameterError(f"plan: expected {n_pairs} weights and voxels in [0, {n_vox})")
    if rep.size and (rep.min() < -1 or rep.max() >= n_tasks):
        raise ParameterError(f"plan: expected row tasks in [-1, {n_tasks})")
    kind, s, e, w, J = tasks.T
    if n_tasks and ((s < 0).any() or (e <= s).any() or (e > n_pairs).any() or (kind < 0).any() or (kind > 3).any()):
        raise ParameterError("plan: expected tasks (kind 0-3, start, stop) with 0 <= start < stop <= pairs")
    horner, shared = kind == HORNER, kind == SHARED
    sw = int(plan.shared_w or 0)
    if (horner & (w > 24)).any() or (shared.any() and sw > 24):
        return None  # 2^24 buckets or more
    if (horner & ((w < 1) | (J < 1) | (J > 64))).any() or (shared.any() and sw < 1):
        raise ParameterError(
            "plan: expected HORNER tasks with w >= 1 and 1 <= J <= 64, and shared_w >= 1 for SHARED ones"
        )
    size = np.where(horner, J * ((np.int64(1) << np.where(horner, w, 0)) + 1), 0)
    slot = max(1, int(size.max(initial=0)), (1 << sw) if shared.any() else 0)
    if slot > MAX_BUCKETS:
        return None
    pre = np.asarray(plan.pre if plan.pre is not None else [], dtype=np.int64).reshape(-1, 2)
    pre_v, pre_j = np.ascontiguousarray(pre[:, 0]), np.ascontiguousarray(pre[:, 1])
    if pre.size and (
        pre_v.min() < 0
        or pre_v.max() >= n_vox
        or pre_j.min() < 1
        or pre_j.max() > 64
        or np.unique(pre_v).size < pre_v.size
    ):
        raise ParameterError(f"plan: expected pre entries (voxel in [0, {n_vox}), 1 <= J <= 64), each voxel once")
    pre_start = np.cumsum(pre_j) - pre_j
    pw_off, pw_n = np.full(n_vox, -1, np.int64), np.zeros(n_vox, np.int64)
    pw_off[pre_v], pw_n[pre_v] = pre_start, pre_j
    single = kind == SINGLE
    return PlanTables(
        vl=vl,
        wl=wl,
        tasks=tasks,
        rep=rep,
        pre_v=pre_v,
        pre_j=pre_j,
        pre_start=pre_start,
        pw_off=pw_off,
        pw_n=pw_n,
        pw_rows=int(pre_j.sum()),
        slot=slot,
        squarings_pre=int(((pre_j - 1) * sw).sum()),
        duplicate_rows=int((rep >= 0).sum()) - n_tasks,
        precomputed=int((pre_j - 1).sum()),
        powmod=int(single.sum()),
    )


def _ints(values, code: str) -> np.ndarray:
    """A list of ints as int64 (``code`` "q") or uint64 ("Q"): through :mod:`array`, a little faster
    than numpy for a plan's Python lists; anything else through numpy.

    >>> _ints([1, 2**64 - 1], "Q").tolist(), _ints(np.array([3]), "q").dtype
    ([1, 18446744073709551615], dtype('int64'))
    """
    dtype = np.int64 if code == "q" else np.uint64
    if isinstance(values, list):
        try:
            return np.frombuffer(array.array(code, values), dtype=dtype)
        except (OverflowError, TypeError):
            pass
    try:
        return np.asarray(values, dtype=dtype).reshape(-1)
    except OverflowError:
        raise ParameterError("plan: expected weights in [0, 2^64) and voxel indices in [0, 2^63)") from None


def limbs_of(values: Sequence[int], nl: int | None = None) -> np.ndarray:
    """Integers as ``(m, nl)`` limbs (``nl`` default: enough for the largest, at least 1).

    >>> limbs_of([1, 2**32]).tolist()
    [[1, 0], [0, 1]]
    """
    ints = [int(v) for v in values]
    if any(v < 0 for v in ints):
        raise ParameterError("values: expected non-negative integers, got a negative one")
    width = max(1, -(-max((v.bit_length() for v in ints), default=1) // 32))
    return to_limbs(ints, nl or width)


def ints_of(limbs: np.ndarray) -> list[int]:
    """The inverse of :func:`limbs_of`."""
    return from_limbs(limbs)
