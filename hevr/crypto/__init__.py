"""Paillier cryptography: the raw integer layer, keys and key files (hevr's and
python-paillier's), the owner's fast encryption, primes, fixed-point encoding,
:class:`EncryptedNumber` and byte records.

=================  =============================================================
``paillier``       ``raw_`` functions on plain integers (the textbook scheme)
``primes``         prime generation with a known factorisation of p - 1
``owner``          owner-side masks from fixed-base tables mod p² and q², CRT
``keys``           :class:`PublicKey`, :class:`PrivateKey`, key generation
``keyfile``        JSON key files (0600 private files), validation on load
``phe_keys``       python-paillier (``pheutil``) key files, both ways
``encoding``       base-10 fixed-point encoding of floats into Z_n
``number``         :class:`EncryptedNumber`: encrypted floating point
``records``        fixed-width big-endian byte records <-> big integers
=================  =============================================================
"""

from __future__ import annotations

from .encoding import BASE, decode, encode
from .keyfile import load_key
from .keys import PrivateKey, PublicKey, generate_keypair
from .number import EncryptedNumber
from .phe_keys import key_from_phe_dict, phe_key_dict

__all__ = [
    "BASE",
    "EncryptedNumber",
    "PrivateKey",
    "PublicKey",
    "decode",
    "encode",
    "generate_keypair",
    "key_from_phe_dict",
    "load_key",
    "phe_key_dict",
]
