"""The measurements behind ``hevr bench``: one function per kind of table cell.

Every function returns a JSON-able dict of raw numbers; ratios against the paper and the
limits are derived in :mod:`hevr.bench.report`. Renders are always from scratch
(``cache=False``) and timed end to end on the client: graph building, map, reduce,
finishing and packing, as a user waits for them.
"""

from __future__ import annotations

import logging
import shutil
import warnings
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from .. import error_bound, render, render_frame, render_plain
from ..crypto.keys import PrivateKey, generate_keypair
from ..errors import InsecureKeyWarning, RenderPlanError
from ..rendering.geometry.camera import Camera
from ..rendering.geometry.rays import cast_rays
from ..rendering.geometry.weights import brick_weights
from ..store.reader import EncryptedVolume
from ..store.writer import encrypt_volume
from ..volume.phantom import phantom
from .measure import (
    Workers,
    dir_bytes,
    fixed_base_seconds,
    mulmod_seconds,
    timed,
)
from .pipeline import trace_frame

log = logging.getLogger(__name__)

# Tried in order when the planner refuses a render at a tiny key (64 bits cannot hold
# 4 reciprocal digits times 100 samples times 10-bit weights): the first that plans is used
# and recorded in the cell.
PARAM_LADDER: tuple[dict[str, Any], ...] = (
    {"precision": 4, "digits": 3},
    {"precision": 3, "digits": 2},
    {"precision": 2, "digits": 2},
    {"precision": 2, "digits": 1},
    {"precision": 1, "digits": 1},
    {"precision": 0, "digits": 1},
)


@dataclass
class Context:
    """What every case needs: the compute side, a scratch directory, cached keys."""

    workers: Workers
    work: Path
    brick: int
    image: int
    progress: bool = False
    keys: dict[int, tuple[Any, PrivateKey]] = field(default_factory=dict)

    def keypair(self, bits: int) -> tuple[Any, PrivateKey, float]:
        """Cached key pair of ``bits`` and the seconds its generation took (0 if cached)."""
        if bits in self.keys:
            return (*self.keys[bits], 0.0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InsecureKeyWarning)
            (pub, priv), s = timed(lambda: generate_keypair(bits))
        self.keys = {bits: (pub, priv)}  # keep one: owner tables of 3072-bit keys are large
        return pub, priv, s

    def camera(self, shape: tuple[int, ...]) -> Camera:
        return Camera.orbit(tuple(shape), azimuth=30, elevation=20, width=self.image, height=self.image)

    def fresh(self) -> bool:
        """Reset the workers' statistics and peak memory; False if the peak could not be reset."""
        return self.workers.fresh()


def encrypt_case(
    ctx: Context,
    vol: np.ndarray,
    private_key: PrivateKey,
    path: Path,
    *,
    dims: int = 1,
    obfuscate: bool = True,
    brick: int | None = None,
) -> tuple[EncryptedVolume, dict]:
    """Encrypt ``vol`` (scalar if ``dims == 1`` else a ``dims``-vector encoding) on the workers."""
    reset = ctx.fresh()
    brick = brick or ctx.brick
    ev, wall = timed(
        lambda: encrypt_volume(
            vol,
            path,
            private_key,
            brick=brick,
            scalar=dims == 1,
            vector_dims=None if dims == 1 else dims,
            overwrite=True,
            progress=ctx.progress,
            client=ctx.workers.client,
            unsafe_no_obfuscation=not obfuscate,
        )
    )
    st = ctx.workers.take_stats()
    n_ct = int(vol.size) * dims
    cell = {
        "seconds": wall,
        "ciphertexts": n_ct,
        "workers": ctx.workers.n_workers,
        "brick": brick,
        "obfuscated": obfuscate,
        "dims": dims,
        "crypto_core_s": st["seconds"].get("encrypt.crypto", 0.0),
        "write_core_s": st["seconds"].get("encrypt.write", 0.0),
        "peak_rss": ctx.workers.peak_rss(),
        # the ciphertexts themselves; store_bytes is what the store occupies (zstd, crc, metadata)
        "ciphertext_bytes": n_ct * private_key.public_key.ciphertext_bytes,
        "store_bytes": dir_bytes(path),
        "bits": private_key.public_key.bits,
        "peak_reset": reset,
    }
    if obfuscate:
        cell["fixed_base_s"] = fixed_base_seconds(private_key)
    log.info("encrypt %s-bit dims=%d obf=%s: %.2f s", cell["bits"], dims, obfuscate, wall)
    return ev, cell


def render_case(
    ctx: Context,
    ev: EncryptedVolume,
    vol: np.ndarray,
    private_key: PrivateKey,
    *,
    mode: str = "xray",
    sampling: str = "nearest",
    nodes: Any = None,
    finish: str = "server",
) -> dict:
    """Render, decrypt on the client (one core), compare with ``render_plain`` and its bound.

    ``finish="server"`` (the paper's way: the Tables) times the render, then the decryption;
    ``finish="client"`` times :func:`hevr.render_frame` end to end (request → decrypted, units
    decrypted as they complete), its decryption part in ``decrypt_s``."""
    cam = ctx.camera(ev.shape)
    vector_dims = ev.vector_dims if mode == "tf" else None
    last: Exception | None = None
    for params in PARAM_LADDER:
        reset = ctx.fresh()
        t_mul = mulmod_seconds(ev.public_key.bits)
        try:
            if finish == "client":
                frame, wall = timed(
                    partial(
                        render_frame,
                        ev,
                        cam,
                        private_key,
                        mode=mode,
                        sampling=sampling,
                        nodes=nodes,
                        cache=False,
                        client=ctx.workers.client,
                        progress=ctx.progress,
                        **params,
                    )
                )
            else:
                img, wall = timed(
                    partial(
                        render,
                        ev,
                        cam,
                        mode=mode,
                        sampling=sampling,
                        nodes=nodes,
                        cache=False,
                        client=ctx.workers.client,
                        progress=ctx.progress,
                        **params,
                    )
                )
        except RenderPlanError as exc:
            last = exc
            continue
        break
    else:
        return {"refused": str(last)}
    st = ctx.workers.take_stats()
    peak = ctx.workers.peak_rss()
    if finish == "client":
        dec, dec_s = frame.image, frame.stats["decrypt_s"]
        img = SimpleNamespace(n_ciphertexts=frame.stats["ciphertexts"], per_pack=None, stats=frame.stats)
    else:
        dec, dec_s = timed(lambda: img.decrypt(private_key))
    ref, plain_s = timed(
        lambda: render_plain(vol, cam, mode=mode, sampling=sampling, nodes=nodes, vector_dims=vector_dims)
    )
    bound = error_bound(ev, cam, mode, sampling, nodes=nodes, finish=finish, **params)
    err = np.abs(dec - ref)
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    cell = {
        "seconds": wall,
        "decrypt_s": dec_s,
        "plain_s": plain_s,
        "params": params,
        "max_abs_err": float(err.max()),
        "within_bound": bool((err <= bound).all()),
        "ciphertexts": img.n_ciphertexts,
        "per_pack": img.per_pack,
        "workers": ctx.workers.n_workers,
        "samples": int(rays.n_samples.sum()),
        "hit_rays": int((rays.n_samples > 0).sum()),
        "pairs": int(st["counts"].get("map.kernel", 0)),
        "kernel_core_s": st["seconds"].get("map.kernel", 0.0),
        "phases_core_s": st["seconds"],
        "mulmod_s": t_mul,
        "peak_rss": peak,
        "bits": ev.public_key.bits,
        "map_tasks": img.stats.get("map_tasks"),
        "peak_reset": reset,
        "finish": finish,
    }
    log.info(
        "render %s/%s %d-bit: %.2f s (decrypt %.2f s, max err %.2e)",
        mode,
        sampling,
        cell["bits"],
        wall,
        dec_s,
        cell["max_abs_err"],
    )
    return cell


def remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def naive_phe_case(size: int, image: int, bits: int) -> dict:
    """What a Python user would write with python-paillier: one ``EncryptedNumber`` per voxel,
    and per pixel ``sum(w * E(v)) * (1 / n)`` with float weights (phe aligns exponents by
    itself). The (ray, voxel) weights come from hevr's own geometry, computed for one brick
    holding the whole volume (so per ray, not split by brick), 6 decimal digits; one core."""
    import phe

    vol = phantom(size)
    cam = Camera.orbit(vol.shape, azimuth=30, elevation=20, width=image, height=image)
    rays = cast_rays(cam, vol.shape, (1.0, 1.0, 1.0), 1.0)
    (ppub, ppriv), keygen_s = timed(lambda: phe.generate_paillier_keypair(n_length=bits))
    encs, enc_s = timed(lambda: [ppub.encrypt(int(v)) for v in vol.ravel().tolist()])
    out: dict[str, Any] = {
        "size": size,
        "image": image,
        "bits": bits,
        "keygen_s": keygen_s,
        "encrypt_s": enc_s,
        "ciphertexts": len(encs),
    }
    for sampling in ("nearest", "trilinear"):
        bw = brick_weights(rays, vol.shape, (1.0, 1.0, 1.0), vol.shape, (0, 0, 0), sampling, 1.0, 6)
        scale = 10.0**bw.exponent
        ip, vx, wt = bw.indptr.tolist(), bw.voxels.tolist(), (bw.weights * scale).tolist()
        inv = (1.0 / rays.n_samples[bw.rays]).tolist()

        pixels, render_s = timed(partial(_phe_pixels, encs, ip, vx, wt, inv))
        vals, dec_s = timed(partial(_phe_decrypt, ppriv, pixels))
        ref = bw.apply(vol.astype(np.float64)) / rays.n_samples[bw.rays]
        plain = render_plain(vol, cam, sampling=sampling).ravel()[bw.rays]
        out[sampling] = {
            "render_s": render_s,
            "decrypt_s": dec_s,
            "pixels": len(pixels),
            "pairs": bw.n_pairs,
            "max_abs_err": float(np.abs(np.asarray(vals) - ref).max()),
            "max_abs_err_plain": float(np.abs(np.asarray(vals) - plain).max()),
        }
        log.info("phe naive %s: render %.2f s, decrypt %.2f s", sampling, render_s, dec_s)
    return out


def _phe_pixels(encs: list[Any], ip: list[int], vx: list[int], wt: list[float], inv: list[float]) -> list[Any]:
    """Per ray ``sum(w * E(v)) * (1 / n)`` on phe's ``EncryptedNumber`` (ray ``r``'s pairs are
    ``ip[r]:ip[r + 1]`` of ``vx``, ``wt``)."""
    pixels = []
    for r in range(len(inv)):
        acc = encs[vx[ip[r]]] * wt[ip[r]]
        for i in range(ip[r] + 1, ip[r + 1]):
            acc = acc + encs[vx[i]] * wt[i]
        pixels.append(acc * inv[r])
    return pixels


def _phe_decrypt(private_key: Any, pixels: list[Any]) -> list[float]:
    """phe's decryption of each pixel."""
    return [private_key.decrypt(p) for p in pixels]


def hevr_small_case(ctx: Context, size: int, image: int, bits: int) -> dict:
    """hevr on the naive case: same phantom, image and key size, on the benchmark's workers."""
    vol = phantom(size)
    pub, priv, keygen_s = ctx.keypair(bits)
    path = ctx.work / f"small-{bits}.zarr"
    saved = ctx.image
    ctx.image = image
    try:
        ev, enc = encrypt_case(ctx, vol, priv, path, brick=max(2, -(-size // 2)))
        out: dict[str, Any] = {"size": size, "image": image, "bits": bits, "encrypt": enc}
        for sampling in ("nearest", "trilinear"):
            out[sampling] = render_case(ctx, ev, vol, priv, sampling=sampling)
    finally:
        ctx.image = saved
        remove(path)
    return out


def pipeline_case(workers: Workers, ev: EncryptedVolume, camera: Camera) -> dict:
    """A resident volume's second X-ray nearest frame on ``workers``, traced
    (:func:`hevr.bench.pipeline.trace_frame`); the first frame is the warm-up."""
    rv = ev.persist(client=workers.client)
    residency = rv.resident
    assert residency is not None  # persist() returns a handle with it set
    residency.wait()
    try:
        trace_frame(workers.client, rv, camera)
        return trace_frame(workers.client, rv, camera)
    finally:
        residency.release()
