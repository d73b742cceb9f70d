"""Slice planes (multi-planar reformatting): the second kind of view, beside :class:`Camera`.

A :class:`Plane` is a grid of ``height x width`` pixels on a plane of world space (x, y, z),
with an optional *slab* of parallel planes averaged per pixel. Conventions (API.md, "Geometry
conventions": voxel (k, j, i) sits at (i·sx, j·sy, k·sz)):

* ``u`` (increasing column) and ``v`` (increasing row, row 0 at the top) are unit vectors —
  normalised from the given ones — and must be orthogonal (|u·v| <= 1e-6; a sheared pixel grid
  is refused rather than silently straightened; :meth:`Plane.oblique` builds an orthonormal
  pair). The normal is ``n = normalize(u x v)``.
* Pixel (r, c) is centred at ``P(r, c) = origin + c·du·u + r·dv·v``; ``origin`` is the centre
  of pixel (0, 0) and ``(du, dv) = pixel_spacing``, world units per pixel.
* Its slab samples sit at ``P(r, c) + (k - (S - 1)/2)·h·n``, ``k = 0 .. S - 1``, with
  ``S = slab`` and ``h = slab_step``; one plane (S = 1) is the plane itself.
* The pixel's value is the mean of the mode's quantity over those samples that lie in the
  closed voxel-centre box (the same 1e-9 relative face tolerance as rays); a pixel with no
  sample inside has no value (0, and ``hits`` False), like a ray that misses.

So a slice pixel is a short ray: origin ``P(r, c) - (S - 1)/2·h·n``, direction ``n``, samples
at ``t = k·h`` (:meth:`Plane.rays`); because the box is convex its inside samples are one run
``k0 .. k1``, which :func:`hevr.rendering.geometry.rays.cast_rays` turns into ``t_enter = k0·h`` and
``k1 - k0 + 1`` samples of step ``h``. Everything downstream (weights, kernel, planner,
finishing, packing, error bound) is the ray renderer's.

Helpers keep the array's own index order, so nearest sampling reproduces array slices exactly:
:meth:`Plane.axial` (k) is ``vol[k]`` (u = +x, v = +y), :meth:`Plane.coronal` (j) is
``vol[:, j, :]`` (u = +x, v = +z) and :meth:`Plane.sagittal` (i) is ``vol[:, :, i]``
(u = +y, v = +z): the raw array order, a coronal slice with the head at the bottom. For
display, ``hevr decrypt`` and ``hevr.save_png(arr, path, plane=plane)`` turn a slice into the
radiological convention (:func:`hevr.image.orient.orient_slice`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.validate import check_int, check_pixel_ids, check_step
from ...crypto.mac import digest
from ...errors import ParameterError
from .camera import Camera
from .coordinates import vec3
from .plane_grid import PARALLEL_TOL, aligned_grid, oblique_grid, pixel_spacing_of, unit

__all__ = ["Plane", "MAX_SLAB", "view_from_dict"]

# Most parallel planes of one slab (each is one sample per pixel).
MAX_SLAB = 1 << 16
# |u·v| above this (unit vectors) counts as not orthogonal (parallel: plane_grid.PARALLEL_TOL).
_ORTHO_TOL = 1e-6
_FIELDS = ("origin", "u", "v", "width", "height", "pixel_spacing", "slab", "slab_step")


@dataclass(frozen=True)
class Plane:
    """An immutable slice plane producing one short ray (its slab) per pixel.

    Parameters
    ----------
    origin : sequence of 3 floats
        World point (x, y, z) of the centre of pixel (row 0, column 0).
    u, v : sequence of 3 floats
        Directions of increasing column and increasing row (normalised; must be orthogonal).
    width, height : int
        Image size in pixels, >= 1.
    pixel_spacing : float or (du, dv), default 1.0
        World units per pixel along u and v, > 0.
    slab : int, default 1
        Number of parallel planes averaged per pixel (a thick slab), 1 .. MAX_SLAB.
    slab_step : float, default 1.0
        World distance between the slab's planes, > 0 (it is the render's sample step).

    Examples
    --------
    >>> p = Plane((0, 0, 2), (1, 0, 0), (0, 1, 0), width=3, height=2)
    >>> p.normal.tolist()
    [0.0, 0.0, 1.0]
    >>> origins, dirs = p.rays()
    >>> origins[[0, 5]].tolist()
    [[0.0, 0.0, 2.0], [2.0, 1.0, 2.0]]
    >>> Plane.from_dict(p.to_dict()) == p
    True
    >>> Plane((0, 0, 0), (1, 0, 0), (2, 0, 0), width=1, height=1)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: v: expected a direction not parallel to u = (1.0, 0.0, 0.0), got (1.0, 0.0, 0.0)
    """

    origin: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]
    width: int
    height: int
    pixel_spacing: Any = 1.0
    slab: int = 1
    slab_step: float = 1.0

    def __post_init__(self) -> None:
        origin = vec3("origin", self.origin)
        u = unit("u", self.u)
        v = unit("v", self.v)
        if float(np.linalg.norm(np.cross(u, v))) < PARALLEL_TOL:
            raise ParameterError(f"v: expected a direction not parallel to u = {u}, got {v}")
        dot = float(np.dot(u, v))
        if abs(dot) > _ORTHO_TOL:
            angle = math.degrees(math.acos(max(-1.0, min(1.0, dot))))
            raise ParameterError(
                f"v: expected a direction orthogonal to u = {u} (Plane.oblique builds such a "
                f"pair), got {v} at {angle:.6g} degrees"
            )
        width = check_int("width", self.width, 1)
        height = check_int("height", self.height, 1)
        spacing = pixel_spacing_of(self.pixel_spacing)
        slab = check_int("slab", self.slab, 1, MAX_SLAB)
        step = check_step(self.slab_step, "slab_step") + 0.0
        for name, value in (
            ("origin", origin),
            ("u", u),
            ("v", v),
            ("width", width),
            ("height", height),
            ("pixel_spacing", spacing),
            ("slab", slab),
            ("slab_step", step),
        ):
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ identity
    def to_dict(self) -> dict[str, Any]:
        """The plane as a JSON-able dict; ``kind: "plane"`` tells it from a camera's.

        >>> Plane((0, 0, 0), (1, 0, 0), (0, 1, 0), width=2, height=2).to_dict()["kind"]
        'plane'
        """
        return {
            "kind": "plane",
            "origin": list(self.origin),
            "u": list(self.u),
            "v": list(self.v),
            "width": self.width,
            "height": self.height,
            "pixel_spacing": list(self.pixel_spacing),
            "slab": self.slab,
            "slab_step": self.slab_step,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Plane:
        """Rebuild a plane from :meth:`to_dict` output (``kind`` optional; missing keys of the
        defaulted fields take their defaults).

        >>> p = Plane((1, 2, 3), (0, 1, 0), (0, 0, 1), width=4, height=5, slab=3)
        >>> Plane.from_dict(p.to_dict()).key() == p.key()
        True
        """
        if not isinstance(data, dict):
            raise ParameterError(f"data: expected a dict from Plane.to_dict(), got {type(data).__name__}")
        data = dict(data)
        kind = data.pop("kind", "plane")
        if kind != "plane":
            raise ParameterError(f"data: expected kind 'plane', got {kind!r}")
        unknown = sorted(set(data) - set(_FIELDS))
        if unknown:
            raise ParameterError(f"data: expected only the keys {sorted(_FIELDS)}, got extra keys {unknown}")
        missing = sorted({"origin", "u", "v", "width", "height"} - set(data))
        if missing:
            raise ParameterError(f"data: expected the keys origin, u, v, width and height, missing {missing}")
        return cls(**data)

    def key(self) -> str:
        """A stable hex identity (SHA-256 of the canonical JSON, ``kind`` included), equal
        across processes and never equal to a camera's.

        >>> a = Plane((0, 0, 0), (1, 0, 0), (0, 1, 0), width=2, height=2)
        >>> a.key() == Plane([0, 0, 0.0], [2, 0, 0], [0, 1, 0], 2, 2, pixel_spacing=(1, 1)).key()
        True
        """
        return digest(self.to_dict()).hex()

    # ------------------------------------------------------------------ geometry
    @property
    def normal(self) -> np.ndarray:
        """``n = normalize(u x v)``, float64 (3,)."""
        n = np.cross(np.asarray(self.u, dtype=np.float64), np.asarray(self.v, dtype=np.float64))
        return n / np.linalg.norm(n) + 0.0

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u, v, n)`` as float64 arrays.

        >>> [a.tolist() for a in Plane((0, 0, 0), (1, 0, 0), (0, 0, 1), 1, 1).basis()]
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
        """
        return np.asarray(self.u, dtype=np.float64), np.asarray(self.v, dtype=np.float64), self.normal

    @property
    def slab_offsets(self) -> np.ndarray:
        """Signed distances ``(k - (S - 1)/2)·h`` of the slab's planes along the normal.

        >>> Plane((0, 0, 0), (1, 0, 0), (0, 1, 0), 1, 1, slab=3, slab_step=0.5).slab_offsets.tolist()
        [-0.5, 0.0, 0.5]
        """
        return (np.arange(self.slab, dtype=np.float64) - (self.slab - 1) / 2.0) * self.slab_step

    def centres(self, pixels: Any = None) -> np.ndarray:
        """World centres ``origin + c·du·u + r·dv·v`` of the pixels (all, row-major, or the given
        global indices ``row*width + col``), (N, 3) float64, computed elementwise.

        >>> Plane((1, 0, 0), (1, 0, 0), (0, 1, 0), 2, 2, pixel_spacing=(0.5, 2)).centres([3]).tolist()
        [[1.5, 2.0, 0.0]]
        """
        pix = np.arange(self.width * self.height, dtype=np.int64) if pixels is None else self.check_pixels(pixels)
        rows, cols = np.divmod(pix, self.width)
        u, v, _ = self.basis()
        du, dv = self.pixel_spacing
        centres: np.ndarray = (
            np.asarray(self.origin, dtype=np.float64)
            + (cols * du).astype(np.float64)[:, None] * u
            + (rows * dv).astype(np.float64)[:, None] * v
        )
        return centres

    def rays(self, pixels: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(origins, directions)``, each (N, 3) float64, like :meth:`Camera.rays`.

        The origin of pixel (r, c)'s ray is its first slab sample,
        ``P(r, c) - (S - 1)/2·h·n``; every direction is ``n``. A subset (``pixels``) is
        bit-identical to the same rows of the whole image.

        >>> p = Plane((0, 0, 5), (1, 0, 0), (0, 1, 0), 2, 1, slab=3, slab_step=2)
        >>> o, d = p.rays()
        >>> o.tolist(), d[0].tolist()
        ([[0.0, 0.0, 3.0], [1.0, 0.0, 3.0]], [0.0, 0.0, 1.0])
        """
        centres = self.centres(pixels)
        n = self.normal
        first = -(self.slab - 1) / 2.0 * self.slab_step
        origins = centres + first * n if self.slab > 1 else centres
        return origins, np.broadcast_to(n, centres.shape).copy()

    def check_pixels(self, pixels: Any) -> np.ndarray:
        """``pixels`` as a flat int64 array of global indices in ``[0, width·height)``.

        >>> Plane((0, 0, 0), (1, 0, 0), (0, 1, 0), 2, 2).check_pixels([4])
        Traceback (most recent call last):
        ...
        hevr.errors.ParameterError: pixels: expected indices in [0, 4), got 4..4
        """
        return check_pixel_ids(pixels, self.width, self.height)

    # ------------------------------------------------------------------ helpers
    @classmethod
    def axial(
        cls,
        ev_or_shape: Any,
        k: float,
        *,
        width: int | None = None,
        height: int | None = None,
        pixel_spacing: Any = None,
        slab: int = 1,
        slab_step: float | None = None,
        spacing: Any = None,
    ) -> Plane:
        """The plane z = k·sz: u = +x, v = +y (nearest sampling gives ``vol[k]``, (ny, nx)).

        Parameters
        ----------
        ev_or_shape : tuple (nz, ny, nx) or object with ``.shape`` and ``.spacing``
            The volume (e.g. an encrypted volume) or its array shape.
        k : float
            Layer index in [0, nz - 1]; a fraction lies between two layers.
        width, height, pixel_spacing :
            Default: the volume's own grid (``nx x ny`` pixels of ``(sx, sy)``). Only a size:
            square pixels that fit the volume's extent into it. Only a spacing: the size that
            covers the extent. The grid is centred on the volume.
        slab, slab_step :
            Thick slab of ``slab`` planes ``slab_step`` apart (default: the voxel spacing sz).
        spacing : (sx, sy, sz), optional
            Voxel spacing, overriding ``ev.spacing`` (default (1, 1, 1) for a shape).

        Examples
        --------
        >>> p = Plane.axial((4, 3, 2), 1, spacing=(1, 2, 3))
        >>> p.origin, p.width, p.height, p.pixel_spacing
        ((0.0, 0.0, 3.0), 2, 3, (1.0, 2.0))
        """
        return cls(*aligned_grid(ev_or_shape, spacing, 0, k, width, height, pixel_spacing, slab, slab_step))

    @classmethod
    def coronal(
        cls,
        ev_or_shape: Any,
        j: float,
        *,
        width: int | None = None,
        height: int | None = None,
        pixel_spacing: Any = None,
        slab: int = 1,
        slab_step: float | None = None,
        spacing: Any = None,
    ) -> Plane:
        """The plane y = j·sy: u = +x, v = +z (nearest gives ``vol[:, j, :]``, (nz, nx)); as :meth:`axial`.

        >>> p = Plane.coronal((4, 3, 2), 2)
        >>> p.origin, (p.width, p.height), p.normal.tolist()
        ((0.0, 2.0, 0.0), (2, 4), [0.0, -1.0, 0.0])
        """
        return cls(*aligned_grid(ev_or_shape, spacing, 1, j, width, height, pixel_spacing, slab, slab_step))

    @classmethod
    def sagittal(
        cls,
        ev_or_shape: Any,
        i: float,
        *,
        width: int | None = None,
        height: int | None = None,
        pixel_spacing: Any = None,
        slab: int = 1,
        slab_step: float | None = None,
        spacing: Any = None,
    ) -> Plane:
        """The plane x = i·sx: u = +y, v = +z (nearest gives ``vol[:, :, i]``, (nz, ny)); as :meth:`axial`.

        >>> p = Plane.sagittal((4, 3, 2), 1)
        >>> p.origin, (p.width, p.height), p.normal.tolist()
        ((1.0, 0.0, 0.0), (3, 4), [1.0, 0.0, 0.0])
        """
        return cls(*aligned_grid(ev_or_shape, spacing, 2, i, width, height, pixel_spacing, slab, slab_step))

    @classmethod
    def oblique(
        cls,
        ev_or_shape: Any,
        center: Any = None,
        normal: Any = (0.0, 0.0, 1.0),
        v: Any = None,
        *,
        width: int | None = None,
        height: int | None = None,
        pixel_spacing: Any = None,
        slab: int = 1,
        slab_step: float | None = None,
        spacing: Any = None,
    ) -> Plane:
        """A plane through ``center`` with the given ``normal``, the pixel grid centred on it.

        Parameters
        ----------
        ev_or_shape :
            As for :meth:`axial`.
        center : (x, y, z), optional
            World point at the image centre; default the volume's centre.
        normal : (x, y, z)
            Plane normal (normalised); the image's ``u x v``.
        v : (x, y, z), optional
            Approximate direction of increasing row, made orthogonal to the normal
            (``v = normalize(v - (v·n) n)``, then ``u = v x n``); default +y when the normal is
            closest to the z axis, else +z — so normal (0, 0, 1) gives the axial orientation,
            (0, -1, 0) the coronal and (1, 0, 0) the sagittal one.
        width, height : int, optional
            Default: enough pixels to cover the volume's diagonal.
        pixel_spacing : float or (du, dv), optional
            Default: the smallest voxel spacing.
        slab, slab_step :
            Thick slab (default step: the smallest voxel spacing).
        spacing :
            As for :meth:`axial`.

        Examples
        --------
        >>> p = Plane.oblique((5, 5, 5), normal=(0, 0, 2), width=3, height=3)
        >>> p.origin, p.u, p.v
        ((1.0, 1.0, 2.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
        """
        fields = oblique_grid(ev_or_shape, center, normal, v, width, height, pixel_spacing, slab, slab_step, spacing)
        return cls(*fields)


def view_from_dict(data: Any) -> Camera | Plane:
    """A :class:`Plane` (``kind: "plane"``) or a :class:`Camera` from its ``to_dict`` output.

    >>> type(view_from_dict(Plane((0, 0, 0), (1, 0, 0), (0, 1, 0), 1, 1).to_dict())).__name__
    'Plane'
    """
    if isinstance(data, dict) and data.get("kind") == "plane":
        return Plane.from_dict(data)
    return Camera.from_dict(data)
