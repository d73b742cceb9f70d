"""hevr: privacy-preserving remote volume rendering on Paillier-encrypted volumes."""

from __future__ import annotations

from .errors import (
    CorruptStoreError,
    HevrError,
    IncompleteStoreError,
    InsecureKeyWarning,
    InvalidKeyError,
    KeyMismatchError,
    MissingDependencyError,
    ParameterError,
    PlaintextOverflowError,
    RenderPlanError,
    StoreError,
    StoreExistsError,
    VolumeFormatError,
)

from .camera import Camera
from .density import encode_density, normalize_density
from .encoding import BASE, decode, encode
from .keyfile import load_key
from .keys import PrivateKey, PublicKey, generate_keypair
from .image import EncryptedImage, load_image, save_png, to_uint8
from .io import load_volume, save_volume
from .number import EncryptedNumber
from .phantom import PHANTOM_LEVELS, phantom
from .plain import render_plain
from .renderer import RaySums, clear_cache, error_bound, render
from .store import encrypt_volume
from .volume import EncryptedVolume, open_volume

__version__ = "0.1.0"

__all__ = [
    "generate_keypair",
    "PublicKey",
    "PrivateKey",
    "load_key",
    "EncryptedNumber",
    "encrypt_volume",
    "phantom",
    "Camera",
    "render_plain",
    "render",
    "RaySums",
    "clear_cache",
    "EncryptedImage",
    "load_image",
    "save_png",
    "to_uint8",
    "error_bound",
    "encode_density",
    "normalize_density",
    "PHANTOM_LEVELS",
    "load_volume",
    "save_volume",
    "open_volume",
    "EncryptedVolume",
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
    "VolumeFormatError",
    "MissingDependencyError",
    "InsecureKeyWarning",
]
