"""The kernel backends: hevr's render-path operations on limb batches, through a launcher.

:class:`KernelBackend` implements :class:`~hevr.backends.base.Backend` on top of the kernels of
``render.cuh`` (one independent item per thread: see the source's header) and is shared by every
launcher (:mod:`hevr.backends.cuda.registered`): :class:`~hevr.backends.cuda.registered.CudaHostBackend`
(registered as ``"cuda-host"``) runs them on the host through ctypes, so CI checks the GPU path's
arithmetic, bit for bit, against the ``cpu`` reference; :class:`~hevr.backends.cuda.registered.CudaBackend`
(``"cuda"``) runs them on an NVIDIA GPU through CuPy (:mod:`hevr.backends.cuda.device`).

Where each operation runs
-------------------------
=============================  ===================================================================
``from_bytes`` / ``to_bytes``  kernels: records ↔ limbs (normal form; ``to_bytes`` first leaves
                               Montgomery form with one CIOS product per value)
``first_out_of_range``         kernel on normal-form limbs; on a batch in Montgomery form mod
                               ``upper`` itself only ``x ≠ 0`` is left to check
``ray_products``               kernels: per-voxel powers, then one item per plan task (ONES,
                               SINGLE, HORNER, SHARED exactly as the CPU backend: same products,
                               same :class:`~hevr.backends.base.OpCounter`); rows by numpy gather
``segment_products``           kernel: one item per (segment, component)
``combine``                    kernel: one item per row (subset products and Straus for k ≤ 8)
``pack``                       kernel: one item per packed ciphertext (Horner with interleaved
                               square-and-multiply); the two offset factors ``g^(O·Σ_j B^j)`` are
                               made once per call in Python
``encrypt``                    kernels (``owner.cuh``, :mod:`~hevr.backends.cuda.owner`), one ciphertext
                               per item: with a private key the owner path's fixed-base masks and CRT,
                               with a public key ``(1 + x·n)·r^n``; ``unsafe_no_obfuscation`` or
                               mantissas beyond int64: :class:`~hevr.backends.cpu.CpuBackend` (gmpy2)
``decrypt``                    kernel (``owner.cuh``): CRT decryption, one ciphertext per item (the
                               caller checks the range first, as for every backend)
=============================  ===================================================================

Residues mod N = n² stay in Montgomery form between operations (:mod:`hevr.backends.cuda.residues`);
the first operation that learns N converts a batch in place, once. Inputs are residues in
``[0, N)`` (what the store's range check guarantees); the kernels reduce anything below
``2^(32·NL)``, so a value ≥ N that the CPU backend would pass through unreduced (a one-row
segment, say) comes back reduced here. A modulus the kernels cannot take (even, or over 4096 bits)
and a plan needing more than ``MAX_BUCKETS`` buckets per task run on gmpy2 instead — same results.
So do ``segment_products``, ``combine`` and ``pack`` calls of fewer independent items than the
launcher's ``min_items`` (``cuda``: 128; ``cuda-host``: 0, always the kernels): a GPU thread runs a
chain of 4096-bit products tens of times slower than a CPU core, so a frame's few packed
ciphertexts — two per tile, each a Horner chain of thousands of products — are the CPU's work
(on an H200 such launches of 2 threads made a 24³ frame take 4.5 s; ``gpu_profile_frame.py``
prints a frame's launches).

>>> import numpy as np
>>> from hevr.backends import CudaHostBackend
>>> be = CudaHostBackend()
>>> x = be.from_bytes(np.array([[0, 2], [0, 3], [0, 5]], np.uint8))
>>> be.to_bytes(be.segment_products(x, np.array([0, 2, 3]), 1, 1001), 2).tolist()
[[0, 6], [0, 5]]
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...crypto.keys import PrivateKey
from ...crypto.records import bytes_to_mpz, record_width
from ...errors import ParameterError
from ..base import Backend, OpCounter, ProductPlan
from ..cpu import CpuBackend
from .host import MAX_LIMBS
from .launch import Launcher
from .owner import decrypt_limbs, owner_limbs, public_limbs
from .residues import LimbBatch, Modulus, exponent_words, ints_of, limbs_of, plan_tables

__all__ = ["KernelBackend"]

_CPU = CpuBackend()


class KernelBackend(Backend):
    """:class:`~hevr.backends.base.Backend` on the kernels of ``render.cuh`` (see the module docstring).

    Parameters
    ----------
    launcher : Launcher
        Runs the kernels (the host build, or a device).
    """

    name = "kernels"

    def __init__(self, launcher: Launcher) -> None:
        self._launch = launcher
        self._mods: dict[int, Modulus] = {}

    # -- moduli and forms ----------------------------------------------------------------------
    def _modulus(self, n: int) -> Modulus | None:
        """Montgomery constants of ``n`` (cached), None where the kernels cannot take it."""
        n = int(n)
        M = self._mods.get(n)
        if M is None:
            if n < 3 or n % 2 == 0 or n.bit_length() > 32 * MAX_LIMBS:
                return None
            if len(self._mods) >= 16:
                self._mods.clear()
            M = self._mods[n] = Modulus(n)
        return M

    def _batch(self, values: Any) -> LimbBatch:
        """A LimbBatch of ``values`` (another backend's batch, a list of ints, is converted)."""
        if isinstance(values, LimbBatch):
            return values
        return LimbBatch(limbs_of(values))

    def _mont(self, values: Any, M: Modulus) -> np.ndarray:
        """The batch's limbs in Montgomery form mod ``M.n``; a normal-form batch is converted in place
        (a joined one part by part, so the parts stay converted)."""
        batch = self._batch(values)
        parts = batch.parts
        if parts is not None:
            y = self._launch.join([self._mont(p, M) for p in parts], M.nl)
            batch.state = (y, M.n)
            return y
        limbs, mod = batch.state
        if mod is not None and int(mod) == M.n:
            return limbs
        x = self._normal(batch)
        if x.shape[1] > M.nl:  # values of more limbs than N has (never from a store): reduced on the host
            x = self._launch.host(x).copy()
            high = np.flatnonzero(x[:, M.nl :].any(axis=1))
            x[high, :] = limbs_of([v % M.n for v in ints_of(x[high])], x.shape[1])
            x = np.ascontiguousarray(x[:, : M.nl])
        elif x.shape[1] < M.nl:
            x = self._launch.join([x], M.nl)
        y = self._launch.mont_convert(x, M.r2, M)
        batch.state = (y, M.n)
        return y

    def _normal(self, batch: LimbBatch) -> np.ndarray:
        """Normal-form limbs of a batch (one CIOS product per value from Montgomery form)."""
        if batch.parts is not None:
            rows = [self._normal(p) for p in batch.parts]
            return self._launch.join(rows, max((int(r.shape[1]) for r in rows), default=1))
        limbs, mod = batch.state
        if mod is None:
            return limbs
        M = self._modulus(int(mod))
        assert M is not None  # a batch is in Montgomery form only mod a modulus the kernels took
        return self._launch.mont_convert(limbs, M.unit, M)

    def _few(self, items: int) -> bool:
        """Whether an operation of ``items`` independent chains runs on gmpy2 rather than the
        launcher: fewer than its ``min_items`` (a GPU thread runs a chain of products tens of times
        slower than a CPU core, so a launch of a few long chains loses to the CPU)."""
        return 0 < int(items) < self._launch.min_items

    def _fallback(self, op: str, *args, mod: int | None = None) -> LimbBatch:
        """The CPU backend's ``op`` on mpz copies of the LimbBatch arguments (rare paths, and
        :meth:`_few`'s); with ``mod`` the results reduced as the kernels reduce them (the CPU backend
        passes a one-row segment's value through as it is)."""
        conv = [_CPU.from_bytes(self.to_bytes(a, 4 * a.nl)) if isinstance(a, LimbBatch) else a for a in args]
        out = getattr(_CPU, op)(*conv)
        return LimbBatch(limbs_of([int(v) % mod for v in out] if mod else out))

    # -- conversion ------------------------------------------------------------------------------
    def from_bytes(self, records: np.ndarray) -> LimbBatch:
        if (
            not isinstance(records, np.ndarray)
            or records.dtype != np.uint8
            or records.ndim < 1
            or records.shape[-1] < 1
        ):
            bytes_to_mpz(records)  # the CPU backend's message for a bad array
            raise ParameterError("records: expected a uint8 array of shape (..., width)")  # pragma: no cover
        width = int(records.shape[-1])
        if width > 4 * MAX_LIMBS:
            raise ParameterError(
                f"records: expected ciphertexts of at most {4 * MAX_LIMBS} bytes for backend "
                f"{self.name!r} (keys of up to {MAX_LIMBS * 16} bits), got {width}-byte records"
            )
        limbs, _ = self._launch.records_to_limbs(records.reshape(-1, width), -(-width // 4))
        return LimbBatch(limbs)

    def to_bytes(self, values: Any, width: int) -> np.ndarray:
        if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width < 1:
            raise ParameterError(f"width: expected an integer >= 1, got {width!r}")
        batch = self._batch(values)
        recs, over = self._launch.limbs_to_records(self._normal(batch), int(width))
        if over.any():
            i = int(np.flatnonzero(over)[0])
            bits = ints_of(self._launch.host(self._normal(batch)[i : i + 1]))[0].bit_length()
            raise ParameterError(f"values[{i}]: value of {bits} bits does not fit in {int(width)} bytes")
        return recs

    @property
    def residence(self) -> str:
        """Where resident residues live: ``"host"`` (numpy limbs) or ``"device"`` (the GPU's memory)."""
        return self._launch.residence

    def memory(self) -> tuple[int, int] | None:
        """(free, total) bytes of the device memory resident residues take, None for the host's."""
        return self._launch.memory()

    def frame_bytes(self, resident: int) -> int:
        return self._launch.frame_bytes(resident)

    def residue_bytes(self, width: int) -> int:
        """Memory of one resident value: its limbs, a row of 32-bit words (on the device for ``cuda``).

        >>> from hevr.backends import CudaHostBackend
        >>> CudaHostBackend().residue_bytes(512), CudaHostBackend().residue_bytes(17)
        (512, 20)
        """
        return 4 * -(-int(width) // 4)

    def first_out_of_range(self, values: Any, upper: int) -> int | None:
        batch = self._batch(values)
        limbs, mod = batch.state
        upper = int(upper)
        if upper <= 1:
            return 0 if len(batch) else None
        if mod is not None and int(mod) == upper:
            x, up = limbs, None  # Montgomery residues are < upper: x ≡ 0 iff its form is 0
        else:
            x = self._normal(batch)
            up = None if upper.bit_length() > 32 * x.shape[1] else limbs_of([upper], x.shape[1])[0]
        bad = np.flatnonzero(self._launch.out_of_range(x, up))
        return int(bad[0]) if bad.size else None

    def concat(self, batches: Sequence[Any]) -> LimbBatch:
        """One batch of the values of ``batches`` in order. Where one of them is in Montgomery form
        mod N, all are (converted in place) and joined now; else they are joined on first use,
        when the modulus is known, so that each part — a resident brick — is converted once for
        all frames, not once per frame.

        >>> from hevr.backends import CudaHostBackend
        >>> be = CudaHostBackend()
        >>> x = be.from_bytes(np.array([[0, 2], [0, 3]], np.uint8))
        >>> y = be.segment_products(x, np.array([0, 1, 2]), 1, 1001)
        >>> be.to_bytes(be.concat([y, be.from_bytes(np.array([[1, 0]], np.uint8))]), 2).tolist()
        [[0, 2], [0, 3], [1, 0]]
        """
        parts = [self._batch(b) for b in batches]
        mods = {int(b.modulus) for b in parts if b.parts is None and b.modulus is not None}
        M = self._modulus(mods.pop()) if len(mods) == 1 else None
        if M is not None:
            return LimbBatch(self._launch.join([self._mont(b, M) for b in parts], M.nl), M.n)
        if mods:  # several moduli (not in a render): normal form now
            return LimbBatch(self._normal(LimbBatch.joined([LimbBatch(self._normal(b)) for b in parts])))
        return LimbBatch.joined(parts)

    # -- encryption and decryption: the CPU backend's, through records ------------------------------
    def encrypt(self, key: Any, mantissas, *, unsafe_no_obfuscation: bool = False) -> LimbBatch:
        if not unsafe_no_obfuscation and self._launch.keyholder:  # in a kernel (owner.py): owner path or r^n
            limbs = (owner_limbs if isinstance(key, PrivateKey) else public_limbs)(self._launch, key, mantissas)
            if limbs is not None:
                return LimbBatch(limbs)
        cts = _CPU.encrypt(key, mantissas, unsafe_no_obfuscation=unsafe_no_obfuscation)
        width = record_width(getattr(key, "public_key", key).n)
        return self.from_bytes(_CPU.to_bytes(cts, width))

    def decrypt(self, private_key: Any, values: Any) -> list[int]:
        """CRT decryption in a kernel (``owner.cuh``) where the launcher's ``keyholder`` allows it, else
        the CPU backend's: residues in ``[0, n)`` either way."""
        batch = self._batch(values)
        if not len(batch):
            return []
        if (
            -(-(int(private_key.public_key.nsquare)).bit_length() // 32) > MAX_LIMBS  # beyond the kernels: gmpy2
            or not self._launch.keyholder
        ):
            return _CPU.decrypt(private_key, _CPU.from_bytes(self.to_bytes(batch, 4 * batch.nl)))
        return decrypt_limbs(self._launch, private_key, self._launch.host(self._normal(batch)))

    # -- rendering -------------------------------------------------------------------------------
    def ray_products(
        self, plan: ProductPlan, components, nsquare: int, counter: OpCounter | None = None
    ) -> list[LimbBatch]:
        if not len(components):
            return []
        M = self._modulus(nsquare)
        n_vox = len(components[0])
        t = plan_tables(plan, n_vox) if M is not None else None
        if M is None or t is None:  # an even modulus, or a task with over MAX_BUCKETS buckets: gmpy2
            mpz = [_CPU.from_bytes(self.to_bytes(c, 4 * self._batch(c).nl)) for c in components]
            return [LimbBatch(limbs_of(r)) for r in _CPU.ray_products(plan, mpz, nsquare, counter)]
        rep = t.rep
        out = []
        for comp in components:
            if len(comp) != n_vox:
                raise ParameterError(f"components: expected {n_vox} ciphertexts in each, got {len(comp)}")
            cts = self._mont(comp, M)
            vals, counts = self._launch.ray_products(t, cts, int(plan.shared_w or 0), M)
            if counts.size and counts[:, 0].min() < 0:
                q = int(np.flatnonzero(counts[:, 0] < 0)[0])
                raise ParameterError(f"plan: task {q} has a weight with more digits than its windows")
            out.append(LimbBatch(self._launch.rows(vals, rep, M.one), M.n))
            if counter is not None:
                mul, sq, bits = (int(v) for v in counts.sum(axis=0)) if counts.size else (0, 0, 0)
                counter.add(
                    OpCounter(
                        mulmod=mul,
                        squarings=sq + t.squarings_pre,
                        powmod=t.powmod,
                        powmod_bits=bits,
                        pairs=plan.n_pairs,
                        rows=plan.n_rows,
                        duplicate_rows=t.duplicate_rows,
                        precomputed=t.precomputed,
                    )
                )
        return out

    def with_defines(self, defines: tuple[str, ...]) -> KernelBackend:
        """This backend's kernels compiled with ``defines`` (the source's experiments, e.g.
        ``HEVR_CIOS_REG``), for ``hevr bench --gpu`` to check and time beside the default."""
        return KernelBackend(self._launch.with_defines(defines))

    def stage_times(self, plan: ProductPlan, component: Any, nsquare: int) -> dict[str, float]:
        """Seconds of the stages of one :meth:`ray_products` call on one component (``hevr bench
        --gpu`` splits its end-to-end rate with them): ``plan``, the plan's arrays made on the host;
        ``launch``, the launcher with those arrays on the host (their uploads, the kernels, the
        counts' download); ``kernels``, the same with the arrays already where the kernels run.
        The component is converted to Montgomery form first (not timed)."""
        M = self._modulus(nsquare)
        if M is None:
            raise ParameterError(f"nsquare: the kernels cannot take this modulus ({int(nsquare).bit_length()} bits)")
        cts = self._mont(component, M)
        w = int(plan.shared_w or 0)
        t0 = time.perf_counter()
        t = plan_tables(plan, len(component))
        t1 = time.perf_counter()
        if t is None:
            raise ParameterError(
                "plan: a task needs more buckets than the kernels take (ray_products runs it on gmpy2)"
            )
        self._launch.ray_products(t, cts, w, M)
        t2 = time.perf_counter()
        dev = self._launch.device_tables(t)
        self._launch.ray_products(dev, cts, w, M)  # warm: the device's allocations
        t3 = time.perf_counter()
        self._launch.ray_products(dev, cts, w, M)  # the counts' download waits for the kernels
        return {"plan": t1 - t0, "launch": t2 - t1, "kernels": time.perf_counter() - t3}

    def segment_products(self, values: Any, indptr: np.ndarray, k: int, nsquare: int) -> LimbBatch:
        M = self._modulus(nsquare)
        ip = np.asarray(indptr, dtype=np.int64).reshape(-1)
        if M is None:
            return self._fallback("segment_products", self._batch(values), ip, k, nsquare)
        if ip.size < 1 or ip[0] < 0 or (np.diff(ip) < 1).any() or ip[-1] * k > len(values):
            raise ParameterError(f"indptr: expected increasing offsets within the {len(values) // max(k, 1)} rows")
        if ip.size == 1:
            return LimbBatch(np.zeros((0, M.nl), np.uint32), M.n)
        if self._few((ip.size - 1) * int(k)):
            return self._fallback("segment_products", self._batch(values), ip, k, nsquare, mod=M.n)
        return LimbBatch(self._launch.segments(self._mont(values, M), ip, int(k), M), M.n)

    def combine(self, values: Any, comb: Sequence[Sequence[int]], nsquare: int) -> LimbBatch:
        M = self._modulus(nsquare)
        k, C = len(comb), len(comb[0])
        if M is None:
            return self._fallback("combine", self._batch(values), comb, nsquare)
        if len(values) % k:
            raise ParameterError(f"values: expected rows of {k} values, got {len(values)} values")
        E = exponent_words([comb[i][ch] for ch in range(C) for i in range(k)], "comb").reshape(C, k, -1)
        if not len(values):
            return LimbBatch(np.zeros((0, M.nl), np.uint32), M.n)
        if self._few(len(values) // k):
            return self._fallback("combine", self._batch(values), comb, nsquare, mod=M.n)
        return LimbBatch(self._launch.combine(self._mont(values, M), k, np.ascontiguousarray(E), M), M.n)

    def pack(self, terms: Any, exps: Sequence[int], pack_bits: int, per_pack: int, offset: int, n: int) -> LimbBatch:
        n = int(n)
        M = self._modulus(n * n)
        if M is None:
            return self._fallback("pack", self._batch(terms), exps, pack_bits, per_pack, offset, n)
        m, J, b = len(terms), max(1, int(per_pack)), int(pack_bits)
        R = exponent_words(exps)
        if R.shape[0] != m:
            raise ParameterError(f"exps: expected {m} exponents like terms, got {R.shape[0]}")
        if not m:
            return LimbBatch(np.zeros((0, M.nl), np.uint32), M.n)
        if self._few(-(-m // J)):  # a frame's few packed ciphertexts: long Horner chains, few threads
            return self._fallback("pack", self._batch(terms), exps, pack_bits, per_pack, offset, n, mod=M.n)
        offs = None
        if offset:  # g^(O·Σ_j B^j) = 1 + O·Σ_j B^j·n, for a full group and for the last one
            lens = (J, m - (m - 1) // J * J)
            digits = [sum(1 << (b * j) for j in range(g)) if J > 1 else 1 for g in lens]
            raw = limbs_of([(1 + offset * d * n) % M.n for d in digits], M.nl)
            offs = self._launch.mont_convert(raw, M.r2, M)
        return LimbBatch(self._launch.pack(self._mont(terms, M), R, J, b, offs, M), M.n)
