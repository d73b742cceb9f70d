"""The arithmetic backend interface: every bulk big-integer operation of hevr, on batches.

hevr's cost is modular multiplication of big integers (mod n² of 2·bits bits, mod p² and
q² for the owner). Everything that does it in bulk goes through one small interface, so
that the render graph, the store's writer and readers and the client never touch a big
integer themselves: they hand a backend byte records and public plaintext parameters, and
get byte records back (the one exception is the maintenance check
``EncryptedVolume.verify``, one gcd per brick on gmpy2).
:class:`hevr.backends.cpu.CpuBackend` (gmpy2) is the reference; a GPU backend implements the
same methods and must give bit-identical results.

A batch of residues (:data:`Residues`) is opaque to callers: the CPU backend uses a Python
list of ``gmpy2.mpz``, a GPU backend would use a device array of limbs. Callers may only
``len()`` it and pass it back to the same backend. Conversion between the store's
fixed-width big-endian byte records and a batch happens once per brick (map), once per
group of partials (merge) and once per tile (finish, decryption).

Operations, in the order of the data path
-----------------------------------------
============================  =====================================================
``encrypt(key, m)``           c = (1 + m·n)·r^n mod n²; with a private key the mask is
                              the owner path (fixed-base tables mod p², q², then CRT)
``from_bytes(records)``       (m, W) uint8 -> batch
``to_bytes(batch, W)``        batch -> (m, W) uint8
``first_out_of_range(b, u)``  the range check 0 < c < n² of every brick read
``ray_products(plan, comps)`` per-brick multi-exponentiation ``Π_v c_v^w_rv`` of a
                              :class:`ProductPlan` (made by :mod:`hevr.rendering.pipeline.kernel`)
``segment_products(b, ip)``   ⊕ of consecutive rows (merging partial ray sums)
``combine(b, comb)``          per pixel ``Π_k S_k^Q[k,ch]`` (emphasis / transfer function)
``pack(T, R, ...)``           per value ``T^R`` (Eq. 1 normalisation), offset ``g^O`` and
                              Horner packing ``Π_j (T_j^R_j)^(B^j)``
``decrypt(key, batch)``       CRT decryption to residues in [0, n)
============================  =====================================================

Operation counts of one frame (unit: one product mod n²; S ≈ 0.85 of it is a squaring)
--------------------------------------------------------------------------------------
With P the ray-voxel pairs of all bricks, R hit rays, K stored components (1 for the
scalar channel, k for the Alg. 4 vector), C output channels (1, or 3 for RGB), b the
packing bits and J = ``per_pack`` values per packed ciphertext:

==============  ===============================================================
map             nearest: ≈ P·K (weights 1–2: running products); trilinear:
                ≈ 2.4·P·K (10-bit weights, bucket method; see the kernel's cost model)
merge           Σ_r (b_r − 1)·K for b_r the bricks ray r crosses: one product per
                extra partial sum
combine         xray: 0; emphasize / tf: per pixel 2^K − 1 − K subset products, then
                per channel one squaring and ≤ 1 product per bit of Q[·, ch]
pack            per value b·S + popcount(R_j): the b squarings of the Horner step
                interleaved with the square-and-multiply of T_j^R_j (the top value of
                a ciphertext: one exponentiation, ≈ 1.3·bits(R_j)); per ciphertext one
                product for the offset
decrypt         per packed ciphertext two half-size exponentiations (CRT)
==============  ===============================================================

Encryption of V voxels costs 2·V fixed-base exponentiations with ~bits/(2w) table
products each (w = the table window) plus one CRT — the owner's mask dominates.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

__all__ = ["Backend", "OpCounter", "ProductPlan", "Residues", "ONES", "SINGLE", "HORNER", "SHARED", "SQR_COST"]

Residues = Any
"""A backend's opaque batch of residues (list of gmpy2.mpz on the CPU)."""

SQR_COST = 0.85  # a modular squaring relative to a modular multiplication (kernel's cost model)
ONES, SINGLE, HORNER, SHARED = range(4)  # ProductPlan task kinds


@dataclass
class OpCounter:
    """Modular operations done by a backend's :meth:`Backend.ray_products` (accumulates).

    Attributes
    ----------
    mulmod : int
        Modular multiplications of two operands (``a * b % n2``).
    squarings : int
        Modular squarings (Horner steps, binary powering, per-voxel powers).
    powmod, powmod_bits : int
        Whole exponentiations and the sum of their exponent bit lengths.
    pairs, rows : int
        CSR entries and rows processed (counted once per component).
    duplicate_rows : int
        Non-empty rows served from an identical earlier row (per component).
    precomputed : int
        Per-voxel powers ``c^(2^(w j))``, ``j >= 1``, made for shared buckets.

    Examples
    --------
    >>> c = OpCounter(mulmod=3, squarings=2)
    >>> c.modmuls
    5
    """

    mulmod: int = 0
    squarings: int = 0
    powmod: int = 0
    powmod_bits: int = 0
    pairs: int = 0
    rows: int = 0
    duplicate_rows: int = 0
    precomputed: int = 0

    @property
    def modmuls(self) -> int:
        """Multiplications plus squarings (whole exponentiations excluded)."""
        return self.mulmod + self.squarings

    def add(self, other: OpCounter) -> None:
        """Add the counts of ``other`` into this counter."""
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))


@dataclass
class ProductPlan:
    """What to multiply for one brick (or a worker's group of bricks): the plaintext half of the
    kernel, shared by all components and all backends (made by
    :func:`hevr.rendering.pipeline.kernel.plan_products` as numpy arrays, which an array backend passes
    to its kernels as they are; sequences of ints are accepted too).

    Attributes
    ----------
    n_rows, n_pairs : int
        CSR rows (rays) and non-zero pairs.
    rep : (n_rows,) int64
        Per row, the index of the task computing it, -1 for an empty row (the result is 1).
    vl, wl : (pairs,) int64, uint64
        Voxel and weight of every pair (zero weights dropped).
    tasks : (T, 5) int64
        One ``(kind, start, stop, w, J)`` per distinct row: method (``ONES``, ``SINGLE``,
        ``HORNER``, ``SHARED``), its pair range, radix bits ``w`` and window count ``J``.
    shared_w : int
        Radix of the shared-bucket rows (0 if none).
    pre : (M, 2) int64, optional
        ``(voxel, J_v)`` of the voxels needing per-voxel powers ``c^(2^(w j))`` for shared
        buckets.
    """

    n_rows: int
    n_pairs: int
    rep: Any
    vl: Any
    wl: Any
    tasks: Any
    shared_w: int = 0
    pre: Any = None


class Backend(ABC):
    """Batched modular arithmetic for hevr (see the module docstring for the operations).

    Implementations are stateless apart from caches, picklable by name, and safe to share
    between the tasks of one worker process. Secret material (p, q, owner tables) is only
    ever reached through a private key passed to :meth:`encrypt` / :meth:`decrypt`.
    """

    name: str = ""

    @property
    def residence(self) -> str:
        """Where resident residues live: ``"host"`` (this process's memory) or ``"device"`` (a GPU's
        memory, :meth:`memory` says how much); a device backend maps a worker's resident bricks in one task."""
        return "host"

    def memory(self) -> tuple[int, int] | None:
        """(free, total) bytes of the device memory resident residues take; None for the host's."""
        return None

    def frame_bytes(self, resident: int) -> int:
        """Bytes a frame needs beside ``resident`` bytes of resident residues, in the memory they
        live in (what ``persist`` plans with on a device; 0 for the host's memory)."""
        return 0

    # -- conversion, once per brick / tile --------------------------------------------
    @abstractmethod
    def from_bytes(self, records: np.ndarray) -> Residues:
        """A batch from (m, W) big-endian uint8 records."""

    @abstractmethod
    def to_bytes(self, values: Residues, width: int) -> np.ndarray:
        """(m, width) big-endian uint8 records of a batch."""

    @abstractmethod
    def residue_bytes(self, width: int) -> int:
        """Memory one value of ``width`` record bytes takes in this backend's form, where a
        resident volume keeps it (host or device memory): what ``persist`` plans with."""

    @abstractmethod
    def first_out_of_range(self, values: Residues, upper: int) -> int | None:
        """Index of the first value not in (0, ``upper``), or None (the store's range check)."""

    # -- encryption and decryption -------------------------------------------------------
    @abstractmethod
    def encrypt(
        self, key: Any, mantissas: Sequence[int] | np.ndarray, *, unsafe_no_obfuscation: bool = False
    ) -> Residues:
        """Ciphertexts of signed integer mantissas under ``key`` (owner path for a private key)."""

    @abstractmethod
    def decrypt(self, private_key: Any, values: Residues) -> list[int]:
        """Residues in [0, n) of a batch of ciphertexts (CRT decryption)."""

    def concat(self, batches: Sequence[Residues]) -> Residues:
        """One batch holding the values of ``batches`` in order (a map task that plans over
        several bricks at once indexes their concatenation). This default suits backends whose
        batches are Python lists; an array backend overrides it."""
        out: list = []
        for b in batches:
            out.extend(b)
        return out

    # -- rendering ------------------------------------------------------------------------
    @abstractmethod
    def ray_products(
        self, plan: ProductPlan, components: Sequence[Residues], nsquare: int, counter: OpCounter | None = None
    ) -> list[Residues]:
        """Per component, ``Π_v c_v^w_rv mod n²`` for every row of ``plan``."""

    @abstractmethod
    def segment_products(self, values: Residues, indptr: np.ndarray, k: int, nsquare: int) -> Residues:
        """Rows of ``k`` values, row-major; segment ``s`` is rows ``indptr[s]:indptr[s+1]``
        (non-empty). Returns ``len(indptr) - 1`` rows: the component-wise products."""

    @abstractmethod
    def combine(self, values: Residues, comb: Sequence[Sequence[int]], nsquare: int) -> Residues:
        """Rows of ``k = len(comb)`` values; per row and channel ``ch`` the product
        ``Π_i v_i^comb[i][ch]``. Returns rows of ``len(comb[0])`` values, row-major."""

    @abstractmethod
    def pack(
        self, terms: Residues, exps: Sequence[int], pack_bits: int, per_pack: int, offset: int, n: int
    ) -> Residues:
        """Groups of ``per_pack`` consecutive terms: ``Π_j (T_j^R_j · g^O)^(2^(b·j))`` mod n²
        (``R_j = exps[j]``, ``b = pack_bits``, ``O = offset``, ``g = n + 1``)."""
