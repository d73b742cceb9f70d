"""What every layer shares: input validation, the limits several layers agree on, file I/O,
file signatures and lazy imports.

Leaf modules (standard library, numpy and :mod:`hevr.errors` only): the crypto, volume, store,
rendering, image and service layers import them; they import none of those.

=============================  ===============================================================
:mod:`hevr.core.validate`      one checker per rule, called where data enters hevr
:mod:`hevr.core.limits`        the integrity margin and the size limits of a render and image
:mod:`hevr.core.files`         the one way hevr writes (atomically, never over a file unasked)
                               and reads (regular files only) a file
:mod:`hevr.core.magic`         the first bytes of the files hevr writes
:mod:`hevr.core.lazy`          a package's lazy re-exports (PEP 562)
=============================  ===============================================================
"""
