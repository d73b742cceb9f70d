"""What a refresh of :class:`hevr.viewer.widget.Viewer` reports: the frame against the plaintext
reference (when the notebook has the volume) and the words of the status line.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..rendering.encrypted import error_bound
from ..rendering.geometry.camera import Camera
from ..rendering.reference.plain import render_plain
from ..store.reader import EncryptedVolume

__all__ = ["compare", "status_text"]


def compare(
    ev: EncryptedVolume, volume: np.ndarray, cam: Camera, level: int, kw: dict[str, Any], arr: np.ndarray
) -> tuple[float, float, tuple[float, float]]:
    """The frame ``arr`` against :func:`hevr.render_plain` of the plaintext ``volume``.

    Parameters
    ----------
    ev : EncryptedVolume
        The store the frame was rendered from.
    volume : numpy.ndarray
        Its plaintext.
    cam : Camera
        The frame's camera.
    level : int
        The frame's pyramid level (0: the volume).
    kw : dict
        The render request (:meth:`hevr.viewer.widget.Viewer.request`).
    arr : numpy.ndarray
        The decrypted (or re-coloured) frame.

    Returns
    -------
    tuple
        (largest absolute error, the largest of :func:`hevr.error_bound`, the PNG window: 0 to the
        reference's largest value).
    """
    packing = ev.meta.packing
    # a packed store's reference samples slice by slice (slices=its axis)
    slices: dict[str, Any] = {"slices": packing.axis} if packing is not None else {}
    ref = render_plain(
        volume,
        cam,
        spacing=ev.spacing,
        value_range=ev.value_range,
        vector_dims=ev.vector_dims,
        level=level,
        **slices,
        **kw,
    )
    err = float(np.abs(arr - ref).max()) if arr.size else 0.0
    bound = float(error_bound(ev, cam, level=level or None, **kw).max())
    return err, bound, (0.0, max(float(ref.max()), 1e-12))


def status_text(
    kw: dict[str, Any],
    level: int,
    seconds: float,
    *,
    recolour: bool,
    reused: bool,
    tasks: int | None,
    verified: bool,
    err: float | None,
    bound: float | None,
) -> str:
    """The status line of a frame (plain text; the viewer escapes it).

    >>> status_text({"mode": "xray", "sampling": "nearest"}, 0, 0.25, recolour=False, reused=False,
    ...             tasks=8, verified=True, err=None, bound=None)
    'xray/nearest: 250 ms request → decrypted frame, 8 map tasks, verified'
    """
    took = f"{seconds:.2f} s" if seconds >= 1 else f"{1000 * seconds:.0f} ms"
    if recolour:
        how = f"re-coloured on the client in {1000 * seconds:.1f} ms, no server"
    elif reused:
        how = f"{took} request → decrypted frame, ray sums reused on the cluster (no map step)"
    elif tasks is None:
        how = f"{took} request → decrypted frame"
    else:
        how = f"{took} request → decrypted frame, {tasks} map tasks"
    what = f"preview at pyramid level {level}, " if level else ""
    text = f"{what}{kw['mode']}/{kw['sampling']}: {how}"
    if not recolour:  # a full frame of a verifiable store is checked before it is shown
        text += ", verified" if verified else ", not verified"
    if err is not None:
        text += f"; max |error| vs plaintext {err:.2e} (bound {bound:.2e})"
    return text
