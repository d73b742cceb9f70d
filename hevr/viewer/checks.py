"""The checks a :class:`hevr.viewer.widget.Viewer` makes before it builds a widget: its optional
dependencies, the store, that the private key is the store's (and its policy on tags), the Dask
client beside the key, the plaintext volume's shape and the mode the store's channels allow.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from ..crypto.keys import PrivateKey
from ..errors import MissingDependencyError, ParameterError
from ..image.provenance import refuse_untagged
from ..runtime.scheduler import refuse_foreign_cluster
from ..store.reader import EncryptedVolume

__all__ = ["check_settle", "check_viewer", "import_widgets", "viewer_modes"]


def import_widgets() -> ModuleType:
    """ipywidgets, once anywidget (the drag surface, :mod:`hevr.viewer.drag`) is known to import.

    Raises
    ------
    MissingDependencyError
        Either is missing (``pip install 'hevr[notebook]'``).
    """
    try:
        import anywidget  # noqa: F401  (the drag surface, hevr.viewer.drag)
        import ipywidgets as widgets
    except ImportError as exc:
        raise MissingDependencyError(
            f"Viewer: expected ipywidgets and anywidget (pip install 'hevr[notebook]'), "
            f"got an environment without {exc.name}"
        ) from None
    return widgets


def check_viewer(ev: Any, private_key: Any, volume: np.ndarray | None, client: Any) -> None:
    """Refuse a viewer of ``ev`` with ``private_key`` (and ``volume``, ``client``) before any frame.

    Raises
    ------
    ParameterError
        ``ev`` is no store, ``private_key`` no key or not the store's, ``volume`` not its shape.
    hevr.ForeignClusterError
        ``client`` is another's cluster, beside the key that decrypts the frames here.
    hevr.VerificationError
        The key's policy requires tags the store lacks (:attr:`hevr.PrivateKey.require_tags`).
    """
    if not isinstance(ev, EncryptedVolume):
        raise ParameterError(f"ev: expected an EncryptedVolume (hevr.open_volume), got {type(ev).__name__}")
    if not isinstance(private_key, PrivateKey):
        raise ParameterError(f"private_key: expected a hevr.PrivateKey, got {type(private_key).__name__}")
    if private_key.public_key.fingerprint != ev.meta.fingerprint:
        raise ParameterError(
            "private_key: expected the key of this volume (fingerprint "
            f"{ev.meta.fingerprint[:16]}…), got {private_key.public_key.fingerprint[:16]}…"
        )
    refuse_untagged(ev, private_key)  # the key's policy (hevr.PrivateKey.require_tags), before any frame
    if getattr(ev, "remote", None) is None:  # its frames decrypted here, beside the Dask client
        refuse_foreign_cluster(client, "hevr.Viewer with the private key")
    if volume is not None and tuple(np.shape(volume)) != tuple(ev.shape):
        raise ParameterError(f"volume: expected the plaintext of shape {tuple(ev.shape)}, got {np.shape(volume)}")


def check_settle(settle: Any) -> float | None:
    """``settle``: seconds without slider movement before the full frame (>= 0), or None."""
    if settle is not None and not (isinstance(settle, (int, float)) and settle >= 0):
        raise ParameterError(f"settle: expected seconds >= 0 or None, got {settle!r}")
    return settle


def viewer_modes(ev: EncryptedVolume, mode: str | None) -> tuple[list[str], str]:
    """The modes the store's channels offer (X-ray: the scalar channel; emphasis and transfer
    functions: the vector channel) and the one to start in (default: the first)."""
    modes = ["xray"] * ev.has_scalar + ["emphasize", "tf"] * bool(ev.vector_dims)
    mode = modes[0] if mode is None else mode
    if mode not in modes:
        raise ParameterError(f"mode: expected one of {modes} (the store's channels), got {mode!r}")
    return modes, mode
