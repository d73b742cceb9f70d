"""File signatures: the first bytes of the files hevr writes, one version byte after each.

A leaf module (standard library only), so that code that only tells one kind of file from
another — ``hevr info PATH``, the command line's checks of a ``FRAME`` argument — does not import
the readers (numpy, gmpy2, Dask) to learn eight bytes. The readers, :mod:`hevr.image.header`
and :mod:`hevr.rendering.pipeline.sums`, build their ``MAGIC`` from these.

>>> IMAGE_MAGIC_PREFIX, SUMS_MAGIC_PREFIX
(b'HEVRIMG', b'HEVRSUMS')
"""

from __future__ import annotations

__all__ = ["IMAGE_MAGIC_PREFIX", "SUMS_MAGIC_PREFIX"]

#: An encrypted image (``.hevr`` frame, :mod:`hevr.image`); then its format version byte.
IMAGE_MAGIC_PREFIX = b"HEVRIMG"
#: Encrypted ray sums (``.hevrsums``, :mod:`hevr.rendering.pipeline.sums`); then its format version byte.
SUMS_MAGIC_PREFIX = b"HEVRSUMS"
