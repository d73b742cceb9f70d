"""The encrypted image: what a render returns, the ``.hevr`` file it travels in, its checks,
its decryption on the client and its display.

Module by module:

==============  ================================================================================
``encrypted``   :class:`EncryptedImage`: per-tile pixel ciphertexts (or client-finished ray sums)
                and their public numbers; checked decryption and unpacking (any fault is an
                :class:`hevr.IntegrityError`), ``save`` and ``to_bytes``
``unpack``      the checked unpacking of a tile's plaintexts (shared with the streamed frames)
``files``       :func:`load_image` (a path or an fsspec URL) and :func:`image_from_bytes`: a
                ``.hevr`` file read back, checked whole before an image is returned
``header``      the ``.hevr`` file layout (version 3; version 2 is still read): the header
                written, and a file's header checked before anything is allocated
``checks``      the numbers of an image (render plan, finish, components, ciphertext counts),
                shared by a file's header and an image in memory
``display``     :func:`to_uint8` and :func:`save_png`: a decrypted image windowed and written
``orient``      :func:`orient_slice`: a slice turned the way radiology viewers show it
==============  ================================================================================

The file format is in ``docs/image-format.md``. Each name below is imported from its module
when it is first used (:mod:`hevr.core.lazy`, as :mod:`hevr.rendering` does), so that the light
modules (``header``, ``checks``: numpy and the key code) can be imported without the
decryption and PNG stack.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..core.lazy import attach

if TYPE_CHECKING:  # what static tools read; at run time each name is imported on first use (hevr.core.lazy)
    from .display import save_png, to_uint8
    from .encrypted import EncryptedImage
    from .files import _from_blob as _from_blob
    from .files import image_from_bytes, load_image
    from .header import MAGIC as MAGIC
    from .orient import orient_slice, slice_layout
    from .unpack import _CORRUPT as _CORRUPT
    from .unpack import _unpack_checked as _unpack_checked

__all__ = ["EncryptedImage", "image_from_bytes", "load_image", "orient_slice", "save_png", "slice_layout", "to_uint8"]

# Name -> submodule, imported on first use. Equal to the TYPE_CHECKING imports above. The
# private names are those the rest of hevr imported from the one-module hevr.image of before.
_LAZY = {
    ".display": ("save_png", "to_uint8"),
    ".orient": ("orient_slice", "slice_layout"),
    ".encrypted": ("EncryptedImage",),
    ".unpack": ("_CORRUPT", "_unpack_checked"),
    ".files": ("image_from_bytes", "load_image", "_from_blob"),
    ".header": ("MAGIC",),
}
__getattr__, __dir__ = attach(__name__, _LAZY)
