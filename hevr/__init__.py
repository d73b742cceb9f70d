"""hevr: privacy-preserving remote volume rendering on Paillier-encrypted volumes.

The subpackages follow the data path; every public name is re-exported here, lazily:

=====================  ==========================================================
:mod:`hevr.crypto`     Paillier (``raw_`` layer), keys, key files, owner-side masks,
                       fixed-point encoding, :class:`EncryptedNumber`, byte records
:mod:`hevr.volume`     plaintext volumes: loaders, phantom, densities, Alg. 4 encoding
:mod:`hevr.store`      the encrypted Zarr v3 store: metadata, writer, reader
:mod:`hevr.rendering`  geometry/ (camera, rays, weights), planning/ (modes, planner),
                       pipeline/ (kernel, graph, finishing), reference/ (plain),
                       :func:`render`, :func:`render_plain`
:mod:`hevr.image`      :class:`EncryptedImage`: file format, decryption, PNG
:mod:`hevr.remote`     :func:`connect`: the key holder's client of ``hevr serve`` (data only)
:mod:`hevr.serve`      ``hevr serve``: the render service beside the cluster (Starlette)
:mod:`hevr.viewer`     :class:`Viewer`: the key holder's notebook viewer (ipywidgets)
:mod:`hevr.cli`        the ``hevr`` command
:mod:`hevr.backends`   the arithmetic seam: bulk big-integer work (``cpu`` = gmpy2)
=====================  ==========================================================

``import hevr`` imports none of them: a public name is imported from its submodule when it is
first used (:mod:`hevr.core.lazy`, PEP 562), so that ``import hevr`` and the ``hevr`` command start
in a few tens of milliseconds instead of half a second (Zarr, Dask, distributed, numpy).
``hevr.render`` and ``from hevr import render`` work as before; the ``if TYPE_CHECKING:``
imports below are what static tools and IDEs read.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .core.lazy import attach

if TYPE_CHECKING:  # what static tools and IDEs read; at run time each name is imported on first use
    from .colour import Colouring, Frame
    from .crypto.encoding import BASE, decode, encode
    from .crypto.keyfile import load_key
    from .crypto.keys import PrivateKey, PublicKey, generate_keypair
    from .crypto.number import EncryptedNumber
    from .errors import (
        CorruptStoreError,
        CorruptVolumeError,
        ExistingFileError,
        FileSystemError,
        ForeignClusterError,
        FrameMovedWarning,
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
        RemoteAnswerError,
        RemoteBusyError,
        RemoteConnectError,
        RemoteError,
        RemoteNotFoundError,
        RemoteRefusedError,
        RemoteTimeoutError,
        RemoteUnauthorisedError,
        RenderPlanError,
        StoreError,
        StoreExistsError,
        VerificationError,
        VolumeFormatError,
    )
    from .image.display import save_png, to_uint8
    from .image.encrypted import EncryptedImage
    from .image.files import load_image
    from .image.proof import Expect, FrameProof, proof_of
    from .remote.client import connect
    from .rendering.encrypted import RaySums, clear_cache, error_bound, render
    from .rendering.geometry.camera import Camera
    from .rendering.geometry.plane import Plane
    from .rendering.geometry.views import VIEWS
    from .rendering.packed.image import PackedImage
    from .rendering.pipeline.stream import render_frame
    from .rendering.pipeline.sums import SavedSums, load_sums, recolour
    from .rendering.reference.plain import render_plain, render_slice_plain
    from .rendering.slices import render_slice
    from .runtime.scheduler import own_cluster
    from .store.known import export_known_stores, import_known_stores, known_stores, trust_store
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

# Public name -> the submodule it is imported from, on first use (module docstring). Keep it
# equal to the TYPE_CHECKING imports above (tests/test_lazy_imports.py checks).
_LAZY = {
    ".runtime.scheduler": ("own_cluster",),
    ".colour": ("Colouring", "Frame"),
    ".crypto.encoding": ("BASE", "decode", "encode"),
    ".crypto.keyfile": ("load_key",),
    ".crypto.keys": ("PrivateKey", "PublicKey", "generate_keypair"),
    ".crypto.number": ("EncryptedNumber",),
    ".errors": (
        "CorruptStoreError",
        "CorruptVolumeError",
        "ExistingFileError",
        "FileSystemError",
        "ForeignClusterError",
        "FrameMovedWarning",
        "HevrError",
        "IncompleteStoreError",
        "InsecureKeyWarning",
        "IntegrityError",
        "InvalidKeyError",
        "KeyFilePermissionWarning",
        "KeyMismatchError",
        "MemoryLimitError",
        "MissingDependencyError",
        "MissingFileError",
        "NotRegularFileError",
        "ParameterError",
        "PlaintextOverflowError",
        "RemoteAnswerError",
        "RemoteBusyError",
        "RemoteConnectError",
        "RemoteError",
        "RemoteNotFoundError",
        "RemoteRefusedError",
        "RemoteTimeoutError",
        "RemoteUnauthorisedError",
        "RenderPlanError",
        "StoreError",
        "StoreExistsError",
        "VerificationError",
        "VolumeFormatError",
    ),
    ".image.display": ("save_png", "to_uint8"),
    ".image.encrypted": ("EncryptedImage",),
    ".image.files": ("load_image",),
    ".image.proof": ("Expect", "FrameProof", "proof_of"),
    ".remote.client": ("connect",),
    ".rendering.geometry.camera": ("Camera",),
    ".rendering.packed.image": ("PackedImage",),
    ".rendering.encrypted": ("RaySums", "clear_cache", "error_bound", "render"),
    ".rendering.reference.plain": ("render_plain", "render_slice_plain"),
    ".rendering.geometry.plane": ("Plane",),
    ".rendering.slices": ("render_slice",),
    ".rendering.pipeline.stream": ("render_frame",),
    ".rendering.pipeline.sums": ("SavedSums", "load_sums", "recolour"),
    ".rendering.geometry.views": ("VIEWS",),
    ".store.known": ("export_known_stores", "import_known_stores", "known_stores", "trust_store"),
    ".store.pyramid": ("build_pyramid",),
    ".store.reader": ("EncryptedVolume", "open_volume"),
    ".store.upgrade": ("upgrade_store",),
    ".store.writer": ("encrypt_volume",),
    ".viewer": ("Viewer",),
    ".volume.density": ("encode_density", "normalize_density"),
    ".volume.loaders": ("load_volume", "read_scan", "save_volume"),
    ".volume.modality": (
        "MODALITY_RANGES",
        "TF_PRESETS",
        "modality_range",
        "range_hint",
        "tf_preset",
        "window_density",
    ),
    ".volume.phantom": ("PHANTOM_LEVELS", "phantom"),
    ".volume.samples": ("sample_scan",),
    ".volume.scan": ("Scan",),
}
__getattr__, __dir__ = attach(__name__, _LAZY)


__all__ = [
    "BASE",
    "MODALITY_RANGES",
    "PHANTOM_LEVELS",
    "TF_PRESETS",
    "VIEWS",
    "Camera",
    "Colouring",
    "CorruptStoreError",
    "CorruptVolumeError",
    "EncryptedImage",
    "EncryptedNumber",
    "EncryptedVolume",
    "ExistingFileError",
    "Expect",
    "FileSystemError",
    "ForeignClusterError",
    "Frame",
    "FrameMovedWarning",
    "FrameProof",
    "HevrError",
    "IncompleteStoreError",
    "InsecureKeyWarning",
    "IntegrityError",
    "VerificationError",
    "InvalidKeyError",
    "KeyFilePermissionWarning",
    "KeyMismatchError",
    "MemoryLimitError",
    "MissingDependencyError",
    "MissingFileError",
    "NotRegularFileError",
    "ParameterError",
    "PackedImage",
    "PlaintextOverflowError",
    "Plane",
    "PrivateKey",
    "PublicKey",
    "RaySums",
    "RemoteError",
    "RemoteTimeoutError",
    "RemoteConnectError",
    "RemoteBusyError",
    "RemoteUnauthorisedError",
    "RemoteNotFoundError",
    "RemoteRefusedError",
    "RemoteAnswerError",
    "RenderPlanError",
    "SavedSums",
    "Scan",
    "StoreError",
    "StoreExistsError",
    "Viewer",
    "VolumeFormatError",
    "build_pyramid",
    "clear_cache",
    "connect",
    "decode",
    "encode",
    "encode_density",
    "encrypt_volume",
    "error_bound",
    "export_known_stores",
    "generate_keypair",
    "import_known_stores",
    "known_stores",
    "load_image",
    "load_key",
    "load_sums",
    "load_volume",
    "modality_range",
    "normalize_density",
    "open_volume",
    "own_cluster",
    "phantom",
    "proof_of",
    "range_hint",
    "read_scan",
    "recolour",
    "trust_store",
    "render",
    "render_frame",
    "render_plain",
    "render_slice",
    "render_slice_plain",
    "sample_scan",
    "save_png",
    "save_volume",
    "tf_preset",
    "to_uint8",
    "upgrade_store",
    "window_density",
]
