"""The pinhole / parallel camera of the public contract (API.md, "Geometry conventions").

A :class:`Camera` is an immutable value: two cameras with the same parameters compare
equal, hash equal and have the same :meth:`Camera.key`, so renders can be cached by
camera. All ray geometry is float64 numpy and follows VTK:

* ``d = normalize(focal_point - position)``, ``right = normalize(d x view_up)``,
  ``up = right x d``;
* pixel ``(r, c)`` with row 0 at the top has ``u = ((c + 0.5)/width*2 - 1)*aspect`` and
  ``v = 1 - (r + 0.5)/height*2`` with ``aspect = width/height``;
* perspective: ``origin = position``,
  ``direction = normalize(d + tan(view_angle/2)*(u*right + v*up))``;
* parallel: ``origin = position + parallel_scale*(u*right + v*up)``, ``direction = d``.

:meth:`Camera.orbit` frames a volume; its ``view=`` presets (``"anterior"``, …,
:data:`Camera.VIEWS`) put the camera on one side of the patient in hevr's RAS+ patient
frame (:mod:`hevr.rendering.geometry.views`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.validate import check_int, check_pixel_ids
from ...crypto.mac import digest
from ...errors import ParameterError
from .coordinates import MAX_COORDINATE, finite_float, vec3, volume_geometry
from .views import VIEWS, view_offset

__all__ = ["Camera"]

# The default framing leaves this much room around the volume's bounding sphere.
_FRAME_MARGIN = 1.05
# |d x view_up| below this (both unit vectors) counts as parallel: the basis would be
# numerically meaningless.
_PARALLEL_TOL = 1e-9
# Smallest |focal_point - position| and |view_up|, relative to the largest coordinate
# (at least 1): below it the view direction or the up direction is lost in rounding.
_MIN_RELATIVE = 1e-9


def _view_angle(value: Any) -> float:
    angle = finite_float("view_angle", value, "degrees in (0, 180)")
    if not 0.0 < angle < 180.0:
        raise ParameterError(f"view_angle: expected degrees in (0, 180), got {value!r}")
    return angle


def _normalize(v: np.ndarray) -> np.ndarray:
    unit: np.ndarray = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return unit


@dataclass(frozen=True)
class Camera:
    """An immutable VTK-style camera producing one ray per pixel.

    Parameters
    ----------
    position, focal_point : sequence of 3 floats
        Eye point and the point looked at, in world coordinates (x, y, z).
    view_up : sequence of 3 floats, default (0, 1, 0)
        Approximate up direction; must not be parallel to the view direction.
    view_angle : float, default 30.0
        Full vertical view angle in degrees, in (0, 180). Used by perspective cameras and
        to default ``parallel_scale``.
    width, height : int, default 150
        Image size in pixels.
    parallel : bool, default False
        Parallel (orthographic) projection instead of perspective.
    parallel_scale : float or None
        Half of the view's height in world units for parallel projection. ``None``
        defaults to ``distance * tan(view_angle/2)``, the half-height a perspective
        camera sees at the focal point, so toggling ``parallel`` keeps the framing.

    Examples
    --------
    >>> cam = Camera((0, 0, 10), (0, 0, 0), width=3, height=2)
    >>> origins, dirs = cam.rays()
    >>> origins.shape, dirs.shape
    ((6, 3), (6, 3))
    >>> Camera.from_dict(cam.to_dict()) == cam
    True
    """

    position: tuple[float, float, float]
    focal_point: tuple[float, float, float]
    view_up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    view_angle: float = 30.0
    width: int = 150
    height: int = 150
    parallel: bool = False
    parallel_scale: float | None = None

    #: The anatomical presets of :meth:`orbit` (``view=``), :data:`hevr.rendering.geometry.views.VIEWS`.
    VIEWS = VIEWS

    def __post_init__(self) -> None:
        # Frozen dataclass: normalise fields through object.__setattr__.
        pos = vec3("position", self.position)
        foc = vec3("focal_point", self.focal_point)
        up = vec3("view_up", self.view_up)
        angle = _view_angle(self.view_angle)
        width = check_int("width", self.width, 1)
        height = check_int("height", self.height, 1)
        if not isinstance(self.parallel, (bool, np.bool_)):
            raise ParameterError(f"parallel: expected True or False, got {self.parallel!r}")
        dist_vec = np.subtract(foc, pos)
        distance = float(np.linalg.norm(dist_vec))
        tiny = _MIN_RELATIVE * max(1.0, *map(abs, pos), *map(abs, foc))
        if distance == 0.0:
            raise ParameterError(f"focal_point: expected a point different from position, got {foc} == position")
        if distance < tiny:
            raise ParameterError(
                f"focal_point: expected a point at least {tiny:.3g} from position ({_MIN_RELATIVE:g} "
                f"of the largest coordinate, at least 1), got one {distance:.3g} away"
            )
        up_norm = float(np.linalg.norm(up))
        if not any(up):
            raise ParameterError(f"view_up: expected a non-zero vector, got {up}")
        if up_norm < _MIN_RELATIVE:
            raise ParameterError(
                f"view_up: expected a vector of length at least {_MIN_RELATIVE:g}, got {up} (length {up_norm:.3g})"
            )
        if np.linalg.norm(np.cross(dist_vec / distance, np.asarray(up) / up_norm)) < _PARALLEL_TOL:
            raise ParameterError(
                f"view_up: expected a direction not parallel to the view direction "
                f"focal_point - position = {tuple(dist_vec.tolist())}, got {up}"
            )
        if self.parallel_scale is None:
            scale = distance * math.tan(math.radians(angle) / 2.0)
        else:
            scale = finite_float("parallel_scale", self.parallel_scale, "a positive number or None")
            if not 0.0 < scale <= MAX_COORDINATE:
                raise ParameterError(
                    f"parallel_scale: expected a positive number of at most {MAX_COORDINATE:g} or None, "
                    f"got {self.parallel_scale!r}"
                )
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "focal_point", foc)
        object.__setattr__(self, "view_up", up)
        object.__setattr__(self, "view_angle", angle)
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "height", height)
        object.__setattr__(self, "parallel", bool(self.parallel))
        object.__setattr__(self, "parallel_scale", scale)

    # ------------------------------------------------------------------ identity
    def to_dict(self) -> dict[str, Any]:
        """Return the camera as a JSON-able dict (floats, ints, bools and lists).

        Examples
        --------
        >>> Camera((0, 0, 5), (0, 0, 0)).to_dict()["position"]
        [0.0, 0.0, 5.0]
        """
        return {
            "position": list(self.position),
            "focal_point": list(self.focal_point),
            "view_up": list(self.view_up),
            "view_angle": self.view_angle,
            "width": self.width,
            "height": self.height,
            "parallel": self.parallel,
            "parallel_scale": self.parallel_scale,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Camera:
        """Rebuild a camera from :meth:`to_dict` output (missing keys take defaults).

        Examples
        --------
        >>> cam = Camera((1, 2, 3), (0, 0, 0))
        >>> Camera.from_dict(cam.to_dict()).key() == cam.key()
        True
        """
        if not isinstance(data, dict):
            raise ParameterError(f"data: expected a dict from Camera.to_dict(), got {type(data).__name__}")
        allowed = {"position", "focal_point", "view_up", "view_angle", "width", "height", "parallel", "parallel_scale"}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ParameterError(f"data: expected only the keys {sorted(allowed)}, got extra keys {unknown}")
        missing = sorted({"position", "focal_point"} - set(data))
        if missing:
            raise ParameterError(f"data: expected the keys position and focal_point, missing {missing}")
        return cls(**data)

    def key(self) -> str:
        """A stable hex identity (SHA-256 of the canonical JSON), equal across processes.

        Examples
        --------
        >>> Camera((0, 0, 5), (0, 0, 0)).key() == Camera([0, 0, 5.0], [0, 0, 0]).key()
        True
        """
        return digest(self.to_dict()).hex()

    # ------------------------------------------------------------------ geometry
    @property
    def aspect(self) -> float:
        """``width / height``."""
        return self.width / self.height

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the orthonormal camera frame ``(d, right, up)`` as float64 arrays.

        Examples
        --------
        >>> d, right, up = Camera((0, 0, 5), (0, 0, 0)).basis()
        >>> d.tolist(), right.tolist(), up.tolist()
        ([0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        """
        d = _normalize(np.subtract(self.focal_point, self.position, dtype=np.float64))
        right = _normalize(np.cross(d, np.asarray(self.view_up, dtype=np.float64)))
        up = np.cross(right, d)
        # + 0.0 turns the -0.0 a cross product can produce into 0.0 (cosmetic only).
        return d + 0.0, right + 0.0, up + 0.0

    def rays(self, pixels: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(origins, directions)``, each (N, 3) float64.

        Ray ``row*width + col`` belongs to pixel (row, col), row 0 at the top;
        directions are unit vectors. ``pixels`` (global indices ``row*width + col``)
        selects a subset; every ray is computed elementwise, so a subset is bit-identical
        to the same rows of the whole image (a render task casts only its own rays).

        Examples
        --------
        >>> o, d = Camera((0, 0, 5), (0, 0, 0), width=1, height=1).rays()
        >>> o.tolist(), d.tolist()
        ([[0.0, 0.0, 5.0]], [[0.0, 0.0, -1.0]])
        >>> cam = Camera((1, 2, 5), (0, 0, 0), width=4, height=3)
        >>> bool((cam.rays([2, 7])[1] == cam.rays()[1][[2, 7]]).all())
        True
        """
        d, right, up = self.basis()
        pix = np.arange(self.width * self.height, dtype=np.int64) if pixels is None else self.check_pixels(pixels)
        rows, cols = np.divmod(pix, self.width)
        uu = (((cols + 0.5) / self.width * 2.0 - 1.0) * self.aspect).reshape(-1, 1)
        vv = (1.0 - (rows + 0.5) / self.height * 2.0).reshape(-1, 1)
        offset = uu * right + vv * up
        n = pix.size
        pos = np.asarray(self.position, dtype=np.float64)
        if self.parallel:
            origins = pos + self.parallel_scale * offset
            directions = np.broadcast_to(d, (n, 3)).copy()
        else:
            origins = np.broadcast_to(pos, (n, 3)).copy()
            directions = _normalize(d + self.tan_half * offset)
        return origins, directions

    def check_pixels(self, pixels: Any) -> np.ndarray:
        """``pixels`` as a flat int64 array of global indices in ``[0, width·height)``.

        >>> Camera((0, 0, 5), (0, 0, 0), width=2, height=2).check_pixels([3, 0]).tolist()
        [3, 0]
        >>> Camera((0, 0, 5), (0, 0, 0), width=2, height=2).check_pixels([4])
        Traceback (most recent call last):
        ...
        hevr.errors.ParameterError: pixels: expected indices in [0, 4), got 4..4
        """
        return check_pixel_ids(pixels, self.width, self.height)

    @property
    def tan_half(self) -> float:
        """``tan(view_angle / 2)``: the image half-height at unit distance (perspective)."""
        return math.tan(math.radians(self.view_angle) / 2.0)

    # ------------------------------------------------------------------ orbit
    @classmethod
    def orbit(
        cls,
        ev_or_shape: Any,
        azimuth: float = 0.0,
        elevation: float = 0.0,
        width: int = 150,
        height: int = 150,
        view_angle: float = 30.0,
        distance: float | None = None,
        spacing: Any = None,
        parallel: bool = False,
        view: str | None = None,
    ) -> Camera:
        """A camera on a sphere around the volume centre, looking at the centre.

        Parameters
        ----------
        ev_or_shape : tuple (nz, ny, nx) or object with ``.shape`` and ``.spacing``
            The volume (e.g. an encrypted volume) or its array shape.
        azimuth, elevation : float
            Degrees. ``0, 0`` puts the camera on the +z side looking towards -z with
            view-up +y. Azimuth rotates about the y axis (90 -> the +x side),
            elevation tilts the camera up (90 -> above, looking down -y). With a ``view``,
            both are relative to it: azimuth about the view's up axis (towards the image's
            right), elevation towards that axis.
        width, height, view_angle :
            As for :class:`Camera`.
        distance : float or None
            Distance from the centre, at most 5e11 world units; ``None`` fits the bounding
            sphere of the voxel-centre box into the narrower of the two view angles, with a
            5 % margin (and at most 5e11 away).
        spacing : (sx, sy, sz) or None
            World-order voxel spacing; overrides ``ev.spacing``; default (1, 1, 1).
        parallel : bool
            Parallel projection; ``parallel_scale`` then frames the bounding sphere.
        view : {"anterior", "posterior", "left", "right", "superior", "inferior"} or None
            An anatomical preset for scans in the RAS+ patient frame (+x right, +y anterior,
            +z superior; what :func:`hevr.read_scan` returns): the side of the patient the
            camera is on. ``"anterior"`` looks at the patient's front with superior up and
            the patient's right on the image's left, as in radiology; the table of all six
            is in :mod:`hevr.rendering.geometry.views`. ``None``: the plain orbit above.

        Examples
        --------
        >>> cam = Camera.orbit((10, 20, 30), width=4, height=4)
        >>> cam.focal_point
        (14.5, 9.5, 4.5)
        >>> front = Camera.orbit((10, 20, 30), view="anterior")
        >>> front.basis()[0].tolist(), front.view_up
        ([0.0, -1.0, 0.0], (0.0, 0.0, 1.0))
        """
        shape, spacing = volume_geometry(ev_or_shape, spacing)
        az = math.radians(finite_float("azimuth", azimuth, "degrees"))
        el = math.radians(finite_float("elevation", elevation, "degrees"))
        width = check_int("width", width, 1)
        height = check_int("height", height, 1)
        angle = _view_angle(view_angle)
        extent = np.array(
            [(shape[2] - 1) * spacing[0], (shape[1] - 1) * spacing[1], (shape[0] - 1) * spacing[2]], dtype=np.float64
        )
        centre = extent / 2.0
        # Bounding sphere of the voxel-centre box; never 0 so 1-voxel volumes still work.
        with np.errstate(over="ignore"):  # an infinite extent is refused below, naming spacing
            radius = max(float(np.linalg.norm(extent)) / 2.0, max(spacing) / 2.0) * _FRAME_MARGIN
        aspect = width / height
        half_v = math.radians(angle) / 2.0
        half_h = math.atan(aspect * math.tan(half_v))
        if not math.isfinite(radius) or float(np.linalg.norm(centre)) + radius > MAX_COORDINATE / 4:
            raise ParameterError(
                f"spacing: expected a volume of at most {MAX_COORDINATE / 4:g} world units "
                f"across (shape·spacing), got {shape} voxels of spacing {spacing}"
            )
        if distance is None:  # at most MAX_COORDINATE / 2 away (only a sliver of a view angle needs more)
            dist = min(radius / math.sin(min(half_v, half_h)), MAX_COORDINATE / 2)
        else:
            dist = finite_float("distance", distance, "a positive number or None")
            if not 0.0 < dist <= MAX_COORDINATE / 2:
                raise ParameterError(
                    f"distance: expected a positive number of at most {MAX_COORDINATE / 2:g} or None, got {distance!r}"
                )
        if view is not None:
            offset, up = view_offset(view, az, el)
            view_up = tuple(up.tolist())
        else:
            ca, sa, ce, se = math.cos(az), math.sin(az), math.cos(el), math.sin(el)
            offset = np.array([ce * sa, se, ce * ca])
            # The orthogonalised +y: equals (0, 1, 0) at elevation 0, stays well defined
            # (and continuous) at elevation +-90 where +y is parallel to the view direction.
            view_up = (-se * sa, ce, -se * ca)
        return cls(
            position=tuple(centre + dist * offset),
            focal_point=tuple(centre),
            view_up=view_up,
            view_angle=angle,
            width=width,
            height=height,
            parallel=bool(parallel),
            parallel_scale=radius / min(1.0, aspect) if parallel else None,
        )
