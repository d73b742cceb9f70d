"""The ``.hevr`` file read back: :func:`load_image` (a path or an fsspec URL) and
:func:`image_from_bytes` (the bytes ``hevr serve`` answers a render with).

:meth:`hevr.image.EncryptedImage.save` and :meth:`~hevr.image.EncryptedImage.to_bytes` write
them. The whole file is checked before an image is returned (:func:`hevr.image.header.parse_file`):
its SHA-256 trailer, then every header field, each before anything sized by it is allocated.
File format: ``docs/image-format.md``. A packed store's frame file (magic ``HEVRIMGP``,
:meth:`hevr.PackedImage.save`) is read by :mod:`hevr.rendering.packed.files`: both readers
return the frame the file holds, so one loader serves ``hevr decrypt`` and ``hevr info``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.files import read_regular
from ..errors import MissingFileError, ParameterError
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.files import is_packed_frame, parse_packed
from ..rendering.packed.image import PackedImage
from ..rendering.packed.verified import PackedVerification
from ..rendering.verification import Verification
from ..store.paths import check_storage_options, is_local, normalise, read_bytes
from .encrypted import EncryptedImage
from .header import parse_file
from .stamp import saved_name

__all__ = ["image_from_bytes", "load_image", "saved_name"]


def load_image(path: str | Path, *, storage_options: dict[str, Any] | None = None) -> Any:
    """Read an image written by :meth:`EncryptedImage.save` (format version 3; version-2 files are read
    as server-finished images), or a packed frame written by :meth:`hevr.PackedImage.save` (a :class:`hevr.PackedImage`,
    checked by :func:`hevr.rendering.packed.files.parse_packed`: any fault an ``IntegrityError``).

    The whole file is checked before an image is returned (``docs/image-format.md``): its
    SHA-256 trailer (:class:`hevr.IntegrityError` on a mismatch: any flipped bit) and every
    header field (:class:`hevr.CorruptStoreError` naming the field), each before anything
    sized by it is allocated. Version-1 files are refused with a ``CorruptStoreError``.
    ``path`` may be an fsspec URL, read with ``storage_options``.
    """
    so = check_storage_options(storage_options)
    if "://" in str(path) and not is_local(normalise(path)):
        path = normalise(path)
        try:
            blob = read_bytes(path, so)
        except FileNotFoundError:
            raise MissingFileError("path", "an encrypted image file", path) from None
        except OSError as exc:
            raise ParameterError(f"path: cannot read {path}: {type(exc).__name__}") from None
        return _from_blob(blob, path, saved_name(path))
    path = normalise(path) if "://" in str(path) else path
    # never blocks: a FIFO, a folder or a device is a NotRegularFileError before a byte is read
    blob = read_regular(path, "path", "an encrypted image file")
    return _from_blob(blob, str(path), saved_name(path))


def image_from_bytes(blob: bytes, where: str = "image") -> Any:
    """The image in the bytes of a ``.hevr`` file, checked as :func:`load_image` checks a file
    (``where`` names it in messages): data only, every field bounded before it is used."""
    if not isinstance(blob, (bytes, bytearray, memoryview)):
        raise ParameterError(f"blob: expected the bytes of a .hevr file, got {type(blob).__name__}")
    return _from_blob(bytes(blob), where)


def _from_blob(blob: bytes, path: str, name: str | None = None) -> Any:
    """The image in the bytes of a ``.hevr`` file (``path`` names it in messages; ``name``: the
    file name it was read under, which a stamp must have been made for); a packed frame's file
    goes to its own reader."""
    if is_packed_frame(blob):
        fields = parse_packed(blob, path)
        v, stamp = fields.pop("verification"), fields.pop("stamp")
        channel, k = fields.pop("channel"), fields.pop("components")
        v = None if v is None else PackedVerification(**v, drawn_here=False)
        stamp = None if stamp is None else stamp._replace(read_as=name)
        if channel == "scalar":
            return PackedImage(**fields, verification=v, stamp=stamp)
        tiles, T = fields.pop("ciphertexts"), fields["plan"].n_tiles  # a colour frame: component-major
        comps = [PackedImage(**fields, ciphertexts=tiles[j * T : (j + 1) * T]) for j in range(k)]
        return PackedColourImage(components=comps, verification=v, stamp=stamp, channel=channel)
    h, body = parse_file(blob, path)
    width = h["width"]
    cts, pos = [], 0
    for c in h["counts"]:
        cts.append(body[pos : pos + c * width].reshape(c, width))
        pos += c * width
    return EncryptedImage(
        shape=h["shape"],
        exponent=h["exponent"],
        offset=h["offset"],
        fingerprint=h["fingerprint"],
        n=h["n"],
        tile=h["tile"],
        pack_bits=h["pack_bits"],
        per_pack=h["per_pack"],
        ciphertexts=cts,
        hits=h["hits"],
        info=h["info"],
        bound=h["bound"],
        finish=h["finish"],
        channel=h["channel"],
        components=h["components"],
        samples=h["samples"],
        verification=None
        if h["verification"] is None
        else Verification.from_dict(h["verification"], int(h["n"]), path),
        stamp=None if h["stamp"] is None else h["stamp"]._replace(read_as=name),
    )
