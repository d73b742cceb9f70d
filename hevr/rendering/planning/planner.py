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

Client finishing (:func:`plan_sums`, the default of :func:`hevr.render`) stops after the ray
sums: the server packs S_k + O, O = max(0, −lo)·W_max, bound = max(0, hi)·W_max + O
(lo, hi the channel's mantissa range, W_max = max_r W_r), with no combination and no
reciprocal; the client divides and colours (:mod:`hevr.colour`). Neither the combination
matrix nor K enters its plan, so nothing of the colouring reaches the server.

Integrity margin. Every decrypted plaintext is checked by the client (``EncryptedImage``):
a packed plaintext must lie below B^J (J = ``per_pack``) and each of its digits in
[0, bound]; an unpacked one in [0, bound]. The planner keeps κ bits of every plaintext
unused (κ = 64 for keys of 256 bits and more, a quarter of the bits of toy keys:
:func:`hevr.core.limits.integrity_bits`): J·b + κ <= bits(n) − 1, so B^J·2^κ <= n/2 < n, and a
plaintext that is uniform in Z_n (what a corrupted ciphertext decrypts to, see
docs/security.md) passes the check with probability below 2^-κ. Renders whose bound needs
more than bits(n) − 1 − κ bits are refused; the intermediate sums S and T, never decrypted,
only need to stay below n/3.

Size limits (:func:`check_render_size`). Before anything is allocated per pixel or per
sample, a render is refused with :class:`hevr.RenderPlanError` when

* its image has more than ``hevr.limits.max-pixels`` pixels (width·height; default
  4096² = 16 777 216), naming ``width``/``height``; or
* its rays take more than ``hevr.limits.max-samples`` samples in all (default 2^31),
  naming ``step``. Each ray takes at most ``diagonal/step + 1`` samples (the voxel-centre
  box's world diagonal), so ``pixels·(diagonal/step + 1)`` bounds the total from public
  data alone; only when that bound exceeds the limit are the exact per-ray counts computed
  (:func:`~hevr.rendering.geometry.rays.cast_rays`, whose memory is linear in the — already
  bounded — pixel count).

Both are Dask config keys: ``dask.config.set({"hevr.limits.max-pixels": 8192**2})``, a
``dask.yaml``, or ``DASK_HEVR__LIMITS__MAX_PIXELS`` / ``DASK_HEVR__LIMITS__MAX_SAMPLES`` in
the environment; values are integers in [1, 2^26] (pixels: the largest image a ``.hevr`` file
holds) and [1, 2^53] (samples); :mod:`hevr.core.limits` holds them. The defaults leave every setting this
project uses far inside (the paper's 150² image of a 100³ volume at step 1 takes < 4·10^6
samples; the largest benchmark, 150² through 200³, < 8·10^6) while refusing in
milliseconds what could not finish anyway: the plaintext renderer needs ~100 bytes and the
encrypted one a modular multiplication of key size per sample, so 2^31 samples are
already minutes of numpy or hours of ciphertext work, and a 4096² image is 50 times the
paper's pixel count. The per-pixel arrays of a 4096² render (rays, counts, hits) take
about 1 GB; raise the limits on purpose for more.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ...core.limits import (
    DEFAULT_MAX_PIXELS,
    DEFAULT_MAX_SAMPLES,
    FLOAT_MAX,
    INTEGRITY_BITS,
    MAX_PIXELS_KEY,
    MAX_SAMPLES_KEY,
    fits_float,
    integrity_bits,
    render_limits,
)
from ...core.validate import check_shape, check_spacing, check_step
from ...errors import ParameterError, RenderPlanError
from ...store.metadata import VolumeMetadata
from ...store.packing import mantissa_range
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from ..geometry.rays import RaySet, cast_rays
from .modes import RenderSpec

__all__ = [
    "DEFAULT_MAX_PIXELS",
    "DEFAULT_MAX_SAMPLES",
    "INTEGRITY_BITS",
    "MAX_PIXELS_KEY",
    "MAX_SAMPLES_KEY",
    "RenderPlan",
    "check_render_size",
    "max_ray_samples",
    "plan_render",
    "plan_sums",
    "render_limits",
]


@dataclass(frozen=True)
class RenderPlan:
    """All public integers that shape one render (frozen; JSON-able via ``to_dict``)."""

    mode: str
    sampling: str
    channel: str  # "scalar", "vector" or "gradient"
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
    channels_out: int  # values per hit pixel: the mode's channels, or the stored components (client finishing)
    precision: int
    finish: str = "server"  # "server": combined, normalised and packed on the server; "client": sums packed

    def to_dict(self) -> dict:
        d = asdict(self)
        d["comb"] = [list(r) for r in self.comb] if self.comb is not None else None
        d["offset"] = str(self.offset)
        d["bound"] = str(self.bound)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RenderPlan:
        d = dict(d)
        d["comb"] = tuple(tuple(int(x) for x in r) for r in d["comb"]) if d.get("comb") is not None else None
        d["offset"] = int(d["offset"])
        d["bound"] = int(d["bound"])
        return cls(**d)

    def reciprocal(self, n_samples: np.ndarray) -> list[int]:
        """R_r = round(10^G / (n_r·K)) for every pixel (0 where n_r = 0); client finishing
        packs the sums themselves: R_r = 1 for every hit pixel."""
        if self.finish == "client":
            return [1 if int(n) else 0 for n in np.asarray(n_samples).ravel().tolist()]
        num = 10**self.recip_digits
        out = []
        for n in np.asarray(n_samples).ravel().tolist():
            den = int(n) * self.factor
            out.append((2 * num + den) // (2 * den) if den else 0)
        return out


def _bits(x: int) -> int:
    return max(1, int(x).bit_length())


def plan_render(
    *,
    n: int,
    spec: RenderSpec,
    meta: VolumeMetadata,
    n_samples: np.ndarray,
    digits: int,
    precision: int,
    comb_digits: int,
    pack: bool,
    combination: np.ndarray | None,
    finish: str = "server",
) -> RenderPlan:
    """Plan a render and refuse it when any mantissa could reach n/3.

    The arguments come checked from :func:`hevr.render`: the channel read, the number of
    output channels and K are the :class:`~hevr.rendering.planning.modes.RenderSpec`'s.
    ``finish="client"`` plans :func:`plan_sums` instead (``combination`` and ``precision``
    unused: nothing of the colouring reaches the plan).
    """
    if finish == "client":
        return plan_sums(
            n=n, channel=spec.channel, sampling=spec.sampling, meta=meta, n_samples=n_samples, digits=digits, pack=pack
        )
    limit = int(n) // 3
    key_bits = int(n).bit_length()
    channel = spec.channel
    info = getattr(meta, channel)
    ch_exp = int(info.exponent)
    if channel == "scalar":
        lo_m, hi_m = mantissa_range(meta.value_range, ch_exp)
    else:  # vector and gradient components lie in [0, 1]: mantissas in [0, 10^digits]
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
    kappa = integrity_bits(key_bits)
    room = key_bits - 1 - kappa  # bits a decrypted plaintext may use (module docstring)
    pack_bits = _bits(bound)
    if pack_bits > room:
        raise RenderPlanError(
            f"overflow planner: the normalised mantissa could reach {pack_bits} bits but a {key_bits}-bit key "
            f"keeps {kappa} bits of every decrypted plaintext for the integrity check, leaving "
            f"{max(room, 0)} bits; {tips}"
        )
    per_pack = max(1, room // pack_bits) if pack else 1
    exponent = w_exp + ch_exp + comb_exp - G
    if not fits_float(max(offset, m_bound), exponent):  # the image check (hevr.image.checks) would refuse it
        raise RenderPlanError(
            f"overflow planner: value_range: expected values whose render fits a float64 (at most "
            f"{FLOAT_MAX:.4g}), got the store's value_range ({meta.value_range[0]:g}, {meta.value_range[1]:g}), "
            f"whose pixels could reach {max(offset, m_bound)}e{exponent}"
        )
    return RenderPlan(
        mode=spec.mode,
        sampling=spec.sampling,
        channel=channel,
        weight_digits=int(digits),
        weight_exponent=w_exp,
        channel_exponent=ch_exp,
        comb=comb,
        comb_digits=int(comb_digits),
        recip_digits=G,
        factor=K,
        offset=int(offset),
        exponent=exponent,
        bound=int(bound),
        pack_bits=pack_bits if pack else 0,
        per_pack=per_pack,
        channels_out=spec.channels,
        precision=int(precision),
    )


def plan_sums(
    *, n: int, channel: str, sampling: str, meta: VolumeMetadata, n_samples: np.ndarray, digits: int, pack: bool
) -> RenderPlan:
    """Plan a client-finished render (:mod:`hevr.colour`): the server packs the K component ray
    sums S_k of ``channel`` themselves, with no combination and no reciprocal.

    S_k of a ray with weight sum W_r lies in [lo·W_r, hi·W_r] (lo, hi the channel's mantissa
    range), so with W_max the largest weight sum, the public offset O = max(0, −lo)·W_max and
    bound = max(0, hi)·W_max + O, every packed value S_k + O lies in [0, bound] — the smallest
    uniform width this public data proves. Only public numbers enter: the key, the store's
    channel metadata, the sample counts and the weight digits; never a density, a node or a colour.

    >>> from hevr.store.metadata import ChannelInfo
    >>> from types import SimpleNamespace as NS
    >>> meta = NS(scalar=ChannelInfo(exponent=0, digits=None), value_range=(0.0, 255.0))
    >>> p = plan_sums(n=2**2047 + 1, channel="scalar", sampling="nearest", meta=meta,
    ...               n_samples=np.array([0, 100, 173]), digits=0, pack=True)
    >>> p.bound, p.pack_bits, p.per_pack, p.offset, p.exponent
    (44115, 16, 123, 0, 0)
    """
    limit = int(n) // 3
    key_bits = int(n).bit_length()
    info = getattr(meta, channel)
    ch_exp = int(info.exponent)
    if channel == "scalar":
        lo_m, hi_m = mantissa_range(meta.value_range, ch_exp)
        comps = 1
    else:  # vector and gradient components lie in [0, 1]: mantissas in [0, 10^digits]
        lo_m, hi_m = 0, 10 ** int(info.digits)
        comps = int(info.dims)
    trilinear = sampling == "trilinear"
    ns = np.asarray(n_samples, dtype=np.int64).ravel()
    n_max = int(ns.max()) if ns.size else 0
    w_max = n_max * ((10 ** int(digits) + 4) if trilinear else 1)
    offset = max(0, -lo_m) * w_max
    bound = max(0, hi_m) * w_max + offset
    tips = "use a larger key or fewer weight digits= (trilinear)"
    if max(abs(lo_m), abs(hi_m)) * w_max >= limit or bound >= limit:
        raise RenderPlanError(
            f"overflow planner: the ray sum could reach {_bits(bound)} bits but a {key_bits}-bit "
            f"key allows plaintexts below n/3 (~{key_bits - 2} bits); {tips}"
        )
    kappa = integrity_bits(key_bits)
    room = key_bits - 1 - kappa
    pack_bits = _bits(bound)
    if pack_bits > room:
        raise RenderPlanError(
            f"overflow planner: the ray sum could reach {pack_bits} bits but a {key_bits}-bit key keeps {kappa} bits "
            f"of every decrypted plaintext for the integrity check, leaving {max(room, 0)} bits; {tips}"
        )
    exponent = (-int(digits) if trilinear else 0) + ch_exp
    if not fits_float(max(offset, bound), exponent):
        raise RenderPlanError(
            f"overflow planner: value_range: expected values whose ray sums fit a float64 (at most {FLOAT_MAX:.4g}), "
            f"got the store's value_range ({meta.value_range[0]:g}, {meta.value_range[1]:g}), whose sums could "
            f"reach {bound}e{exponent}"
        )
    return RenderPlan(
        mode="sums",
        sampling=sampling,
        channel=channel,
        weight_digits=int(digits),
        weight_exponent=-int(digits) if trilinear else 0,
        channel_exponent=ch_exp,
        comb=None,
        comb_digits=0,
        recip_digits=0,
        factor=1,
        offset=int(offset),
        exponent=exponent,
        bound=int(bound),
        pack_bits=pack_bits if pack else 0,
        per_pack=max(1, room // pack_bits) if pack else 1,
        channels_out=comps,
        precision=0,
        finish="client",
    )


def max_ray_samples(shape: Any, spacing: Any, step: float) -> float:
    """An upper bound on the samples of any one ray: the voxel-centre box's world diagonal
    over ``step``, plus one (and a hair of slack); ``inf`` when that overflows.

    Examples
    --------
    >>> max_ray_samples((101, 101, 101), (1, 1, 1), 1.0) >= 100 * 3 ** 0.5 + 1
    True
    """
    nz, ny, nx = check_shape(shape)
    sx, sy, sz = check_spacing(spacing)
    diag = math.hypot((nx - 1) * sx, (ny - 1) * sy, (nz - 1) * sz)
    ratio = diag / check_step(step)
    return ratio * (1.0 + 1e-9) + 2.0 if math.isfinite(ratio) else math.inf


def check_render_size(camera: Any, shape: Any, spacing: Any, step: Any) -> RaySet | None:
    """Refuse a render that is too big, before anything is allocated per pixel or sample.

    The one rule behind :func:`hevr.render`, :func:`hevr.error_bound` and
    :func:`hevr.render_plain` (module docstring, "Size limits"): at most
    :func:`render_limits` pixels and samples.

    Parameters
    ----------
    camera : Camera or Plane
    shape : (nz, ny, nx)
    spacing : (sx, sy, sz)
    step : float
        Sample distance in world units (a plane's ``slab_step``).

    Returns
    -------
    RaySet or None
        The cast rays when the exact count needed them (the caller reuses them rather than
        casting twice), else ``None``.

    Raises
    ------
    RenderPlanError
        Too many pixels (the message names ``width``/``height``) or samples (``step``).
    ParameterError
        ``camera`` is not a :class:`~hevr.rendering.geometry.camera.Camera`, a bad shape, spacing or
        step, or a bad limit in the Dask config.

    Examples
    --------
    >>> check_render_size(Camera.orbit((8, 8, 8), width=16, height=16), (8, 8, 8), (1, 1, 1), 1.0)
    >>> check_render_size(Camera.orbit((8, 8, 8), width=16384, height=16384), (8, 8, 8), (1, 1, 1), 1.0)
    Traceback (most recent call last):
        ...
    hevr.errors.RenderPlanError: width, height: expected an image of at most 16777216 pixels \
(Dask config hevr.limits.max-pixels), got 16384x16384 = 268435456 pixels
    """
    if not isinstance(camera, (Camera, Plane)):
        raise ParameterError(f"camera: expected a hevr.Camera or hevr.Plane, got {type(camera).__name__}")
    shape, spacing, step = check_shape(shape), check_spacing(spacing), check_step(step)
    max_pixels, max_samples = render_limits()
    w, h = camera.width, camera.height
    pixels = w * h
    if pixels > max_pixels:
        raise RenderPlanError(
            f"width, height: expected an image of at most {max_pixels} pixels "
            f"(Dask config {MAX_PIXELS_KEY}), got {w}x{h} = {pixels} pixels"
        )
    if pixels * max_ray_samples(shape, spacing, step) <= max_samples:
        return None
    # The public bound is too loose to decide: count exactly (memory linear in pixels).
    rays = cast_rays(camera, shape, spacing, step)
    counts = rays.n_samples
    top = int(counts.max()) if counts.size else 0
    total = int(counts.sum()) if top * counts.size < 2**63 else float(counts.sum(dtype=np.float64))
    if total > max_samples:
        raise RenderPlanError(
            f"step: expected at most {max_samples} samples in all (Dask config {MAX_SAMPLES_KEY}), got "
            f"{total:.4g} samples for {w}x{h} rays through a {shape[2]}x{shape[1]}x{shape[0]} volume at "
            f"step {step:g}; use a larger step or a smaller image"
        )
    return rays
