"""The plaintext overflow planner: bound every mantissa before any ciphertext is touched.

Paillier plaintexts live in Z_n, and a signed result is only decodable when its magnitude
stays below n/3. Every quantity of a render is bounded from public parameters only —
key size, value range, channel exponents, weight digits, sample counts, combination
matrix and reciprocal digits — and a render that could exceed n/3 is refused with
:class:`hevr.RenderPlanError` naming the knob to turn. No render ever decrypts to garbage.

Per pixel r with n_r samples and K transfer-function nodes (K = 1 otherwise):

* weight sum W_r = n_r (nearest) or <= n_r·(10^d + 4) (trilinear, d weight digits: the
  8 rounded corner weights of a sample add up to at most 10^d + 4);
* component ray sum |S| <= A·W_r, A = largest stored mantissa magnitude of the channel;
* combined value T = Σ_k Q[k, ch]·S_k <= (Σ_k Q[k, ch])·A·W_r, Q the combination matrix
  quantised to ``comb_digits`` (xray: T = S);
* normalised mantissa M = T·R_r with R_r = round(10^G / (n_r·K)), G = precision +
  ceil(log10(max n_r·K)), so R_r has relative error <= 0.5·10^-precision;
* a public offset O = max_r(-lo·W_r·R_r) (only for signed scalar data) makes M + O >= 0,
  so pixels can be packed B = 2^b per ciphertext, b = bits of the largest M + O.

Integrity margin. Every decrypted plaintext is checked by the client (``EncryptedImage``):
a packed plaintext must lie below B^J (J = ``per_pack``) and each of its digits in
[0, bound]; an unpacked one in [0, bound]. The planner keeps κ = ``INTEGRITY_BITS`` = 64
bits of every plaintext unused: J·b + κ <= bits(n) − 1, so B^J·2^κ <= n/2 < n, and a
plaintext that is uniform in Z_n (what a corrupted ciphertext decrypts to, see
docs/security.md) passes the check with probability below 2^-κ. Renders whose bound needs
more than bits(n) − 1 − κ bits are refused; the intermediate sums S and T, never decrypted,
only need to stay below n/3.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import RenderPlanError
from ..store.metadata import VolumeMetadata
from .modes import RenderSpec

__all__ = ["RenderPlan", "plan_render", "INTEGRITY_BITS"]

INTEGRITY_BITS = 64


@dataclass(frozen=True)
class RenderPlan:
    """All public integers that shape one render (frozen; JSON-able via ``to_dict``)."""

    mode: str
    sampling: str
    channel: str  # "scalar" or "vector"
    weight_digits: int
    weight_exponent: int
    channel_exponent: int
    comb: tuple[tuple[int, ...], ...] | None  # (k, C) quantised combination matrix
    comb_digits: int
    recip_digits: int  # G
    factor: int  # K
    offset: int
    exponent: int  # common exponent of every output value
    bound: int  # every packed value M + O lies in [0, bound]
    pack_bits: int
    per_pack: int
    channels_out: int
    precision: int

    def to_dict(self) -> dict:
        d = asdict(self)
        d["comb"] = [list(r) for r in self.comb] if self.comb is not None else None
        d["offset"] = str(self.offset)
        d["bound"] = str(self.bound)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RenderPlan":
        d = dict(d)
        d["comb"] = tuple(tuple(int(x) for x in r) for r in d["comb"]) if d.get("comb") is not None else None
        d["offset"] = int(d["offset"])
        d["bound"] = int(d["bound"])
        return cls(**d)

    def reciprocal(self, n_samples: np.ndarray) -> list[int]:
        """R_r = round(10^G / (n_r·K)) for every pixel (0 where n_r = 0)."""
        num = 10 ** self.recip_digits
        out = []
        for n in np.asarray(n_samples).ravel().tolist():
            den = int(n) * self.factor
            out.append((2 * num + den) // (2 * den) if den else 0)
        return out


def _bits(x: int) -> int:
    return max(1, int(x).bit_length())


def plan_render(*, n: int, spec: RenderSpec, meta: VolumeMetadata, n_samples: np.ndarray, digits: int,
                precision: int, comb_digits: int, pack: bool, combination: np.ndarray | None) -> RenderPlan:
    """Plan a render and refuse it when any mantissa could reach n/3.

    The arguments come checked from :func:`hevr.render`: the channel read, the number of
    output channels and K are the :class:`~hevr.rendering.modes.RenderSpec`'s.
    """
    limit = int(n) // 3
    key_bits = int(n).bit_length()
    channel = spec.channel
    info = meta.scalar if channel == "scalar" else meta.vector
    ch_exp = int(info.exponent)
    if channel == "scalar":
        lo_m = math.floor(meta.value_range[0] * 10 ** (-ch_exp))
        hi_m = math.ceil(meta.value_range[1] * 10 ** (-ch_exp))
    else:
        lo_m, hi_m = 0, 10 ** int(info.digits)
    amax = max(abs(lo_m), abs(hi_m))
    trilinear = spec.sampling == "trilinear"
    w_exp = -int(digits) if trilinear else 0
    ns = np.asarray(n_samples, dtype=np.int64).ravel()
    n_max = int(ns.max()) if ns.size else 0
    K = spec.n_nodes
    per_sample_w = (10 ** int(digits) + 4) if trilinear else 1
    w_max = n_max * per_sample_w
    comb = None
    comb_exp = 0
    if combination is not None:
        q = np.rint(np.asarray(combination) * 10**comb_digits).astype(np.int64)
        comb = tuple(tuple(int(x) for x in row) for row in q)
        comb_exp = -int(comb_digits)
        comb_sum = int(q.sum(axis=0).max())
    else:
        comb_sum = 1
    G = int(precision) + (math.ceil(math.log10(max(n_max * K, 1))) if n_max else 0)
    tips = "use a larger key, a lower precision=, fewer weight digits= (trilinear) or fewer comb_digits="
    s_bound = amax * w_max
    t_bound = comb_sum * s_bound
    # largest W_r·R_r over pixels: W_r <= n_r·per_sample_w and R_r <= 10^G/(n_r K) + 1/2
    wr_max = per_sample_w * (10**G // K + n_max) if n_max else 0
    m_bound = comb_sum * amax * wr_max
    offset = -lo_m * wr_max if lo_m < 0 else 0
    bound = m_bound + offset
    for name, val in (("ray sum", s_bound), ("combined value", t_bound), ("normalised mantissa", bound)):
        if val >= limit:
            raise RenderPlanError(
                f"overflow planner: the {name} could reach {_bits(val)} bits but a {key_bits}-bit key "
                f"allows plaintexts below n/3 (~{key_bits - 2} bits); {tips}"
            )
    room = key_bits - 1 - INTEGRITY_BITS  # bits a decrypted plaintext may use (module docstring)
    pack_bits = _bits(bound)
    if pack_bits > room:
        raise RenderPlanError(
            f"overflow planner: the normalised mantissa could reach {pack_bits} bits but a {key_bits}-bit key "
            f"keeps {INTEGRITY_BITS} bits of every decrypted plaintext for the integrity check, leaving "
            f"{max(room, 0)} bits; {tips}"
        )
    per_pack = max(1, room // pack_bits) if pack else 1
    return RenderPlan(
        mode=spec.mode, sampling=spec.sampling, channel=channel, weight_digits=int(digits),
        weight_exponent=w_exp, channel_exponent=ch_exp, comb=comb, comb_digits=int(comb_digits),
        recip_digits=G, factor=K, offset=int(offset),
        exponent=w_exp + ch_exp + comb_exp - G, bound=int(bound),
        pack_bits=pack_bits if pack else 0, per_pack=per_pack,
        channels_out=spec.channels, precision=int(precision),
    )
