"""``hevr.render_frame``: request → decrypted frame, decrypting each finished piece as it arrives.

A client-finished render (:mod:`hevr.colour`) ends in finishing units — runs of a tile's hit
pixels whose packed ray sums one task produces (:func:`~hevr.rendering.pipeline.finishing.finish_units`).
Each unit is a whole number of packing groups, so the client can check and decrypt it alone.
On a distributed client :func:`render_frame` does so as each unit completes
(:func:`hevr.runtime.scheduler.compute`'s ``on_result``): the client's CRT decryptions overlap the
server's remaining map, merge and finishing work, and the frame's time is measured end to
end — from the request to the decrypted means. On Dask's default scheduler (one machine) the
units are decrypted after the graph has run.

The private key never leaves this process: the graph is the one :func:`hevr.render` builds
(it holds no key and, finished on the client, no colouring); the units come back as public
ciphertexts and are decrypted here with the checks of :meth:`hevr.EncryptedImage.decrypt`
(range of every ciphertext, width and bound of every plaintext: :class:`hevr.IntegrityError`).
"""

from __future__ import annotations

import inspect
import time
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ...backends import get_backend
from ...colour import Frame, frame_from_sums, scaled_sums
from ...crypto.keys import PrivateKey
from ...errors import IntegrityError, KeyMismatchError, ParameterError
from ...image.checks import tile_name
from ...image.provenance import refuse_untagged
from ...image.unpack import _CORRUPT, _unpack_checked
from ...runtime.scheduler import refuse_foreign_cluster
from ..encrypted import render
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from ..view import render_view

if TYPE_CHECKING:
    from ..packed.colour import PackedColourImage
    from ..packed.image import PackedImage

__all__ = ["StreamDecryptor", "render_frame"]


class StreamDecryptor:
    """Checks and decrypts the finishing units of one client-finished render as they come."""

    def __init__(self, private_key: PrivateKey, backend: str | None = None) -> None:
        self.key = private_key
        self.be = get_backend(backend)
        self.decrypt_s = 0.0
        self.ciphertexts = 0

    def start(self, finish: Any, fields: dict[str, Any]) -> None:
        """The plan of the render (its :class:`~hevr.rendering.pipeline.graph.FinishGraph`) and image fields."""
        if fields["finish"] != "client":  # pragma: no cover - render_frame asks for client finishing
            raise ParameterError("finish: expected 'client' for a streamed frame")
        if fields["fingerprint"] != self.key.public_key.fingerprint:
            raise KeyMismatchError(
                f"private_key: the volume is encrypted under key {fields['fingerprint'][:16]}…, "
                f"got a key with fingerprint {self.key.public_key.fingerprint[:16]}…"
            )
        self.finish, self.fields = finish, fields
        self.K = int(fields["components"])
        self.samples = np.asarray(fields["samples"]).ravel()
        self.sums = np.zeros((self.samples.size, self.K), dtype=np.float64)
        self.exact = np.zeros((self.samples.size, self.K), dtype=object)  # the integer sums: a verified frame's check
        self.n = int(fields["n"])
        self.done = 0

    def unit(self, i: int, packed: np.ndarray) -> None:
        """Check and decrypt unit ``i``'s packed ciphertexts into the frame's sums."""
        t0 = time.perf_counter()
        t, a, b = self.finish.units[i]
        layout = self.finish.layout
        pixels = layout.pixels(t)[a:b]
        hit = pixels[self.samples[pixels] > 0]
        need = hit.size * self.K
        J, bits, bound = int(self.fields["per_pack"]), int(self.fields["pack_bits"]), int(self.fields["bound"])
        if packed.shape[0] != -(-need // J):
            raise IntegrityError(
                f"{tile_name(layout, t)}: expected {-(-need // J)} ciphertexts for pixels {a}-{b - 1}, "
                f"got {packed.shape[0]}; {_CORRUPT}"
            )
        if need:
            recs = self.be.from_bytes(packed)
            bad = self.be.first_out_of_range(recs, self.n * self.n)
            if bad is not None:
                raise IntegrityError(
                    f"{tile_name(layout, t)}: ciphertext {bad} of pixels {a}-{b - 1} is not in (0, n²); {_CORRUPT}"
                )
            vals, fault = _unpack_checked(self.be.decrypt(self.key, recs), need, bits, J, bound)
            if fault is not None:
                raise IntegrityError(
                    f"{tile_name(layout, t)}: a value of pixels {a}-{b - 1} decrypts outside the "
                    f"render plan's range; {_CORRUPT}"
                )
            offset = int(self.fields["offset"])
            exact = [v - offset for v in vals]
            self.sums[hit] = scaled_sums(exact, self.fields["exponent"]).reshape(-1, self.K)
            self.exact[hit] = np.array(exact, dtype=object).reshape(-1, self.K)
        self.ciphertexts += int(packed.shape[0])
        self.done += 1
        self.decrypt_s += time.perf_counter() - t0

    def verify(self, img: Any) -> None:
        """The check of a verified frame (:meth:`hevr.rendering.verification.Verification.check`) on the
        sums decrypted as the units came: :class:`hevr.VerificationError` before any frame is returned."""
        rays = np.flatnonzero(self.samples > 0)
        img.verification.check(self.key, img, rays, self.exact[rays].reshape(-1).tolist())

    def frame(self, stats: dict[str, Any], t0: float, colouring: Any = None) -> Frame:
        if self.done != len(self.finish.units):  # pragma: no cover - compute returns every unit
            raise IntegrityError(f"frame: expected {len(self.finish.units)} finished units, got {self.done}")
        H, W = self.fields["shape"][:2]
        stats = dict(stats, decrypt_s=self.decrypt_s, ciphertexts=self.ciphertexts)
        return frame_from_sums(
            self.sums.reshape(H, W, self.K), self.samples.reshape(H, W), self.fields["channel"], colouring, stats, t0=t0
        )


# the keywords of hevr.render that render_frame passes on, with render's defaults
_RENDER_KEYWORDS = {
    name: p.default
    for name, p in inspect.signature(render).parameters.items()
    if p.kind is inspect.Parameter.KEYWORD_ONLY and name not in ("finish", "compute", "keep_sums", "weight_bits")
}  # weight_bits: packed stores


def render_frame(
    ev: Any,
    camera: Any,
    private_key: PrivateKey,
    mode: str = "xray",
    sampling: str = "nearest",
    step: float = 1.0,
    density: float | None = None,
    nodes: Any = None,
    *,
    decrypt_backend: str | None = None,
    **kwargs: Any,
) -> Frame:
    """Render a view finished on the client and decrypt it as it completes: a :class:`hevr.Frame`.

    Parameters
    ----------
    ev, camera, mode, sampling, step, density, nodes
        As for :func:`hevr.render` (``camera`` may be a :class:`hevr.Plane`: a slice). The
        density and nodes stay in this process: they colour the frame (:attr:`Frame.colouring`).
    private_key : PrivateKey
        Decrypts the finished units here; it never enters the graph. Refused
        (:class:`hevr.ForeignClusterError`) beside a Dask client of a cluster this process did not
        start or declare its own (:func:`hevr.own_cluster`); a store of :func:`hevr.connect` renders
        on its server's cluster, data only.
    decrypt_backend : str, optional
        Backend of the client's decryption (default ``cpu``).
    **kwargs
        Any other keyword of :func:`hevr.render` but ``finish``, ``compute`` and ``keep_sums``
        (``client``, ``level``, ``gradient``, ``backend``, ``cache``, ``tile``, ...).

    A verifiable store's frame is verified (``verify``, as for :func:`hevr.render`): its units are
    decrypted as they come, and when the whole frame has arrived the key holder draws the seed, the
    server sums the tags and the frame is checked here before it is returned
    (:class:`hevr.VerificationError` otherwise); ``frame.stats["verified"]`` says whether it was.

    Returns
    -------
    Frame
        ``frame.image`` is the frame under this colouring, ``frame.recolour(...)`` another one;
        ``frame.stats["seconds"]`` the end-to-end time (request to decrypted means),
        ``decrypt_s`` the client's decryption time (overlapping the render on a cluster).
    """
    for bad in ("finish", "compute", "keep_sums"):
        if bad in kwargs:
            raise ParameterError(
                f"{bad}: expected no {bad}= for render_frame (a client-finished frame, computed "
                f"now); use hevr.render for it, got {kwargs[bad]!r}"
            )
    unknown = sorted(set(kwargs) - set(_RENDER_KEYWORDS))
    if unknown:
        raise ParameterError(
            f"{unknown[0]}: expected a keyword of hevr.render ({', '.join(sorted(_RENDER_KEYWORDS))}), "
            f"got {unknown[0]}={kwargs[unknown[0]]!r}"
        )
    if not isinstance(private_key, PrivateKey):
        raise ParameterError(f"private_key: expected a hevr.PrivateKey, got {type(private_key).__name__}")
    if getattr(ev, "remote", None) is None:  # rendered here, on a Dask client, decrypted beside it
        refuse_foreign_cluster(kwargs.get("client"), "render_frame with the private key")
    refuse_untagged(ev, private_key)  # the key's policy: a store without tags is refused before any work
    plane = isinstance(camera, Plane)
    if not plane and getattr(getattr(ev, "meta", None), "packing", None) is not None:
        return _packed_frame(ev, camera, private_key, mode, sampling, step, density, nodes, decrypt_backend, kwargs)
    if plane and kwargs.get("level"):
        raise ParameterError(f"level: expected None for a hevr.Plane (slices have no level), got {kwargs['level']!r}")
    t0 = time.perf_counter()
    stream = StreamDecryptor(private_key, decrypt_backend)
    kw = {**_RENDER_KEYWORDS, **kwargs}  # hevr.render's own defaults: one home
    img = render_view(
        ev,
        camera,
        mode,
        sampling,
        camera.slab_step if plane else step,
        density,
        nodes,
        compute=True,
        keep_sums=None,
        views=(Plane,) if plane else (Camera,),
        finish="client",
        stream=stream,
        **kw,
    )
    stats = dict(img.stats, verified=img.verification is not None)
    if img.verification is not None:  # the frame has settled: the tags' round ran, now the check here
        t1 = time.perf_counter()
        stream.verify(img)
        stats["check_s"] = time.perf_counter() - t1
    return stream.frame(stats, t0, img.colouring)


def _packed_frame(
    ev: Any,
    camera: Any,
    private_key: PrivateKey,
    mode: str,
    sampling: str,
    step: float,
    density: float | None,
    nodes: Any,
    decrypt_backend: str | None,
    kwargs: dict[str, Any],
) -> Frame:
    """:func:`render_frame` on a packed store: the frame rendered whole (:mod:`hevr.rendering.packed`,
    verified on a verifiable store) and decrypted here, checked before any pixel; ``seconds`` end to end."""
    t0 = time.perf_counter()
    img = cast(  # a packed store's frame (hevr.render: rendering.packed.request)
        "PackedImage | PackedColourImage",
        render(ev, camera, mode=mode, sampling=sampling, step=step, density=density, nodes=nodes, **kwargs),
    )
    frame = img.decrypt_frame(private_key, decrypt_backend)
    frame.stats.update(
        verified=img.verified,
        seconds=time.perf_counter() - t0,
        reused_ray_sums=False,
        map_tasks=img.stats.get("map_tasks"),
    )
    return frame  # its stats carry the key holder's check_s (a verified frame)
