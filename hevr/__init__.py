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

from .encoding import BASE, decode, encode
from .keyfile import load_key
from .keys import PrivateKey, PublicKey, generate_keypair
from .number import EncryptedNumber

__version__ = "0.1.0"

__all__ = [
    "generate_keypair",
    "PublicKey",
    "PrivateKey",
    "load_key",
    "EncryptedNumber",
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
