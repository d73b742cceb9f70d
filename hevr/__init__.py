"""hevr: privacy-preserving remote volume rendering on Paillier-encrypted volumes.

The subpackages follow the data path; every public name is re-exported here:

=====================  ==========================================================
:mod:`hevr.crypto`     Paillier (``raw_`` layer), keys, key files, owner-side masks,
                       fixed-point encoding, :class:`EncryptedNumber`, byte records
:mod:`hevr.volume`     plaintext volumes: loaders, phantom, densities, Alg. 4 encoding
:mod:`hevr.store`      the encrypted Zarr v3 store: metadata, writer, reader
:mod:`hevr.rendering`  camera, modes, rays, weights, planner, kernel, graph,
                       finishing, :func:`render`, :func:`render_plain`
:mod:`hevr.image`      :class:`EncryptedImage`: file format, decryption, PNG
:mod:`hevr.viewer`     :class:`Viewer`: the key holder's notebook viewer (ipywidgets)
:mod:`hevr.cli`        the ``hevr`` command
:mod:`hevr.backends`   the arithmetic seam: bulk big-integer work (``cpu`` = gmpy2)
=====================  ==========================================================
"""

from __future__ import annotations

from .colour import Colouring, Frame
from .crypto.encoding import BASE, decode, encode
from .crypto.keyfile import load_key
from .crypto.keys import PrivateKey, PublicKey, generate_keypair
from .crypto.number import EncryptedNumber
from .errors import (
    CorruptStoreError,
    ExistingFileError,
    FileSystemError,
    HevrError,
    IncompleteStoreError,
    InsecureKeyWarning,
    IntegrityError,
    InvalidKeyError,
    KeyFilePermissionWarning,
    KeyMismatchError,
    MemoryLimitError,
    MissingDependencyError,
    MissingFileError,
    NotRegularFileError,
    ParameterError,
    PlaintextOverflowError,
    RenderPlanError,
    StoreError,
    StoreExistsError,
    VolumeFormatError,
)
from .image import EncryptedImage, load_image, save_png, to_uint8
from .rendering.camera import Camera
from .rendering.encrypted import RaySums, clear_cache, error_bound, render
from .rendering.plain import render_plain, render_slice_plain
from .rendering.plane import Plane
from .rendering.slices import render_slice
from .rendering.stream import render_frame
from .rendering.sums import SavedSums, load_sums, recolour
from .rendering.views import VIEWS
from .store.pyramid import build_pyramid
from .store.reader import EncryptedVolume, open_volume
from .store.upgrade import upgrade_store
from .store.writer import encrypt_volume
from .viewer import Viewer
from .volume.density import encode_density, normalize_density
from .volume.loaders import load_volume, read_scan, save_volume
from .volume.modality import (
    MODALITY_RANGES,
    TF_PRESETS,
    modality_range,
    range_hint,
    tf_preset,
    window_density,
)
from .volume.phantom import PHANTOM_LEVELS, phantom
from .volume.samples import sample_scan
from .volume.scan import Scan

__version__ = "0.1.0"

__all__ = [
    "generate_keypair",
    "PublicKey",
    "PrivateKey",
    "load_key",
    "EncryptedNumber",
    "encrypt_volume",
    "phantom",
    "sample_scan",
    "Camera",
    "render_plain",
    "render",
    "render_frame",
    "Frame",
    "Colouring",
    "RaySums",
    "clear_cache",
    "recolour",
    "load_sums",
    "SavedSums",
    "Viewer",
    "Plane",
    "render_slice",
    "render_slice_plain",
    "build_pyramid",
    "EncryptedImage",
    "load_image",
    "save_png",
    "to_uint8",
    "error_bound",
    "encode_density",
    "normalize_density",
    "PHANTOM_LEVELS",
    "load_volume",
    "read_scan",
    "Scan",
    "save_volume",
    "open_volume",
    "EncryptedVolume",
    "upgrade_store",
    "encode",
    "decode",
    "BASE",
    "HevrError",
    "ParameterError",
    "InvalidKeyError",
    "KeyMismatchError",
    "PlaintextOverflowError",
    "RenderPlanError",
    "StoreError",
    "StoreExistsError",
    "IncompleteStoreError",
    "CorruptStoreError",
    "IntegrityError",
    "VolumeFormatError",
    "MissingDependencyError",
    "MissingFileError",
    "MemoryLimitError",
    "ExistingFileError",
    "FileSystemError",
    "NotRegularFileError",
    "InsecureKeyWarning",
    "KeyFilePermissionWarning",
    "VIEWS",
    "MODALITY_RANGES",
    "TF_PRESETS",
    "modality_range",
    "range_hint",
    "tf_preset",
    "window_density",
]
