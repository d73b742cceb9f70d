"""The key holder's client of ``hevr serve``: :func:`connect`, :class:`Server`, :class:`RemoteVolume`.

The trust boundary of the paper: the server renders; the key holder sends requests and receives
ciphertexts, as data, through a narrow protocol that cannot carry code
(:mod:`hevr.remote.protocol`). The key holder's process creates no ``distributed.Client`` and
never unpickles anything the server sends.

====================================  ====================================================
:mod:`hevr.remote.protocol`           requests (strict JSON) and the units stream's frames
:mod:`hevr.remote.client`             :func:`connect`, :class:`Server`: the service's API
:mod:`hevr.remote.connection`         one HTTP exchange with bounds (sizes, retries, no redirects)
:mod:`hevr.remote.transport`          one deadline per exchange, enforced at the socket
:mod:`hevr.remote.failures`           typed failures (busy, unauthorised, …), Retry-After
:mod:`hevr.remote.volume`             :class:`RemoteVolume`: a served store's public side
:mod:`hevr.remote.render`             a remote render, checked against what was asked
====================================  ====================================================
"""

from __future__ import annotations

from .client import Server, connect
from .protocol import RenderRequest, VerifyRequest
from .volume import RemoteVolume

__all__ = ["RemoteVolume", "RenderRequest", "Server", "VerifyRequest", "connect"]
