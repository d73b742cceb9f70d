"""Transfer-function and emphasis frames of packed stores: the vector channel's k ray sums per
intermediate ray, coloured by the key holder (:mod:`hevr.colour`).

A packed store encrypted with ``vector_dims=k`` (:mod:`hevr.store.packed_brick`) holds, beside the
scalar packs, the k components of the density encoding e(d) packed alike: the same S slots of K
bits along the same axis, slot value = the component's mantissa rint(e(d)_c·10^digits) (offset 0).
A frame's weights depend on the view only, never on the channel, so the scalar frame's plan
(:class:`~hevr.rendering.packed.plan.SlicePlan`) serves all k components:

* **map** (one task per column of bricks,
  :func:`~hevr.rendering.packed.colour_render.map_components`): the column's pairs and one product
  plan (:func:`~hevr.rendering.pipeline.kernel.plan_products`), run on the k components' batches at
  once (``ray_products`` takes k components for one plan);
* **merge and combine** (one task per tile,
  :func:`~hevr.rendering.packed.colour_render.merge_components`): the scalar frame's
  :func:`~hevr.rendering.packed.graph.merge_tile`, once per component;
* **the key holder** (:class:`PackedColourImage`): each component's values decoded and checked as
  an X-ray frame's (:class:`~hevr.rendering.packed.image.PackedImage`: integrity margin, every slot
  at most 10^digits·W of its ray), divided by the public sample count and weight unit — the ray's
  mean x_c of component c — warped to the camera's pixels, then coloured exactly as a per-voxel
  client-finished frame is (:func:`hevr.colour.colour`: emphasis x·e(density), transfer function
  (1/N)·x·Σ_i e(d_i)·c_i^T). The warp is linear, so warping the means and colouring commute.

The colouring never leaves the key holder's process (not pickled, never sent). Its reference is
``hevr.render_plain(vol, cam, mode=..., vector_dims=k, slices=True)`` and its bound
:func:`hevr.error_bound` (:mod:`hevr.rendering.packed.sliced`). A verifiable store's colour frame is
verified by default as an X-ray is
(:func:`~hevr.rendering.packed.colour_render.colour_aggregate`): one seed drawn after the values, the
vector tags' k components through the same plan, one aggregate for all k (component j's coefficients
from j·n_values), all components' values checked against it before any mean is formed. Not yet:
frame files.

The frame's render is :mod:`hevr.rendering.packed.colour_render`; this module holds the frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...colour import Frame, colour, colouring_spec
from ...image.provenance import check_provenance
from . import files
from .image import decode
from .plan import SlicePlan

__all__ = ["PackedColourImage"]


@dataclass
class PackedColourImage:
    """An encrypted transfer-function or emphasis frame of a packed store (``hevr.render(ev, cam,
    mode="tf", nodes=...)`` or ``mode="emphasize", density=...`` on a store with the vector channel).

    Attributes
    ----------
    components : list of PackedImage
        Per component c of e(d), its frame of ray sums (the plan, decoding and checks of an X-ray
        frame; values are the component's means, in [0, 1]).
    colouring : Colouring or None
        The render's colouring: kept in this process only (never pickled, saved or sent);
        :meth:`decrypt` applies it unless given another.
    stats : dict
        ``ops`` (map, merge, combine over all components), ``components``, ``ciphertexts``, …
    """

    components: list = field(repr=False)
    colouring: Any = field(default=None, repr=False, compare=False)
    stats: dict = field(default_factory=dict, repr=False)
    verification: Any = field(default=None, repr=False, compare=False)  # one PackedVerification, all k components
    channel: str = "vector"  # or "gradient": g·e(d), the gradient-modulated encoding
    stamp: Any = field(default=None, repr=False, compare=False)  # a file's (stamp, message, saved as, read as)

    def __getstate__(self) -> dict:
        return dict(self.__dict__, colouring=None)

    @property
    def plan(self) -> SlicePlan:
        return self.components[0].plan

    @property
    def meta(self) -> Any:
        """The store's metadata (level 0's; colour frames have no level)."""
        return self.components[0].meta

    level = 0
    finish = "client"  # coloured by the key holder, as a per-voxel client-finished frame

    @property
    def ciphertexts(self) -> list:
        """Every component's tiles, component-major (the frame file's order)."""
        return [t for c in self.components for t in c.ciphertexts]

    @property
    def camera(self) -> Any:
        return self.components[0].camera

    @property
    def fingerprint(self) -> str:
        return self.components[0].fingerprint

    @property
    def store_id(self) -> str:
        return self.components[0].store_id

    @property
    def n(self) -> int:
        return self.components[0].n

    @property
    def shape(self) -> tuple[int, int]:
        return self.components[0].shape

    @property
    def n_ciphertexts(self) -> int:
        return int(sum(c.n_ciphertexts for c in self.components))

    @property
    def verified(self) -> bool:
        """Whether the frame carries a check of all k components against the vector channel's tags
        (drawn in this process), which its decryption runs before any mean is formed."""
        return self.verification is not None

    def decrypt_sums(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """The exact integer ray sums Σ w·q_c of every component c and intermediate ray, (k, N_i, N_j)
        int64: every component's values checked as an X-ray frame's, and a verified frame's all k
        against the tags at once (one aggregate), before any sum is returned."""
        first = self.components[0]
        key = first._key(private_key)
        check_provenance(
            key, self, require_verified, "a store encrypted with verifiable=False, or a render with verify=False"
        )
        if self.verification is not None:  # the metadata first: it says what every number means
            self.verification.check_metadata(key, self.plan, self.fingerprint)
        tiles = [c._decrypted_tiles(key, backend) for c in self.components]
        sums = np.stack([decode(self.plan, t, c.span) for t, c in zip(tiles, self.components)])
        if self.verification is not None:
            t0 = time.perf_counter()
            self.verification.check(key, self.plan, tiles, self.fingerprint)
            self.stats["check_s"] = time.perf_counter() - t0
        return sums

    def decrypt_means(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """Per pixel the mean of each component over its ray's samples, warped to the camera: (H, W, k) float64."""
        geo = self.plan.geometry
        coords = geo.pixel_coords(self.camera)
        sums = self.decrypt_sums(private_key, backend, require_verified=require_verified)
        return np.stack(
            [geo.warp(c._values(s), coords).reshape(self.shape) for c, s in zip(self.components, sums)], axis=-1
        )

    def decrypt_frame(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> Frame:
        """A :class:`hevr.Frame` of the warped means, to colour (and re-colour) on this machine, checked
        as :meth:`decrypt` checks; its ``n_samples`` are the intermediate rays' sample counts warped to
        the pixels, rounded."""
        t0 = time.perf_counter()
        means = self.decrypt_means(private_key, backend, require_verified=require_verified)
        plan = self.plan
        geo = plan.geometry
        counts = geo.warp(geo.sample_counts(plan.sampling).astype(np.float64), geo.pixel_coords(self.camera))
        stats = dict(self.stats, decrypt_s=time.perf_counter() - t0, ciphertexts=self.n_ciphertexts)
        return Frame(
            means=means,
            n_samples=np.rint(counts).astype(np.int64).reshape(self.shape),
            channel=self.channel,
            colouring=self.colouring,
            stats=stats,
        )

    def decrypt(
        self,
        private_key: Any,
        backend: str | None = None,
        *,
        mode: str | None = None,
        density: float | None = None,
        nodes: Any = None,
        require_verified: bool | str | None = None,
    ) -> np.ndarray:
        """The coloured (H, W) (emphasize) or (H, W, 3) (tf) float64 image: with ``mode`` /
        ``density`` / ``nodes`` when given, else the render's own colouring (:func:`hevr.colour.colour`).
        A verified frame's components are each checked against the vector channel's tags first;
        ``require_verified`` (True or a store id) refuses a frame without those checks."""
        spec = colouring_spec(self.channel, len(self.components), mode, density, nodes, self.colouring)
        return colour(self.decrypt_means(private_key, backend, require_verified=require_verified), spec)

    def save(
        self, path: Any, *, overwrite: bool = False, storage_options: dict | None = None, private_key: Any = None
    ) -> None:
        """Write the frame file (a packed frame file with the ``channel`` field: the k components'
        tiles, component-major; ``docs/format.md``), as :meth:`PackedImage.save` does; the colouring
        is not saved (``hevr decrypt --tf / --density`` colours at decryption)."""
        files.save_packed(self, path, overwrite=overwrite, storage_options=storage_options, private_key=private_key)

    def to_bytes(self, private_key: Any = None) -> bytes:
        """The frame file as bytes (:meth:`save`'s rules)."""
        return files.packed_bytes(self, private_key)

    def __repr__(self) -> str:
        return (
            f"PackedColourImage(shape={self.shape}, components={len(self.components)}, "
            f"sampling={self.plan.sampling!r}, ciphertexts={self.n_ciphertexts}, key={self.fingerprint[:16]}…)"
        )
