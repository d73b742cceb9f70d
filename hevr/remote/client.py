"""The key holder's side of the wire: :func:`hevr.connect` and :class:`Server`, the API of
``hevr serve`` (its stores, :meth:`Server.open` for a :class:`~hevr.remote.volume.RemoteVolume`)
over :class:`~hevr.remote.connection.Connection`, which reads every answer as untrusted data, with
bounds: sizes known before reading, no decompression, no redirects, one deadline per exchange,
bounded retries of a busy server, strict JSON, nothing unpickled.

Every failure is a :class:`hevr.RemoteError` naming the server and what was expected, typed
(:mod:`hevr.remote.failures`); ``httpx``, ``ssl`` and ``json`` exceptions never reach the caller.
"""

from __future__ import annotations

from typing import Any

from ..errors import ParameterError, RemoteAnswerError
from .connection import Connection
from .protocol import MAX_BODY, check_store_name, is_store_id
from .volume import RemoteVolume, parse_description, parse_name, parse_stores

__all__ = ["Server", "connect"]

MAX_STORES_BYTES = 16 * MAX_BODY  # the store list: a few KiB of metadata per store


def connect(
    url: str,
    token: str | None = None,
    cafile: str | None = None,
    timeout: float = 60.0,
    *,
    connect_timeout: float = 10.0,
    retries: int = 2,
    transport: Any = None,
) -> Server:
    """Connect to a render server (``hevr serve``) as the key holder.

    Parameters
    ----------
    url : str
        ``http://host:port`` or ``https://host:port`` (plain HTTP only on loopback is wise: tokens
        and ciphertexts travel in the clear otherwise).
    token : str, optional
        The bearer token the server's operator gave you.
    cafile : str, optional
        A CA bundle (PEM) to trust for an ``https`` server, instead of the system's.
    timeout : float
        Seconds for each whole exchange with the server: connecting, sending the request, the
        answer's status line, headers and body, and the waits before retries — one deadline, not
        per read (a server dribbling bytes cannot hold the caller longer). The key holder's own
        work (checking the answer, decrypting, also between a stream's frames) is not counted. A
        verified render makes two exchanges (the image, then the aggregate).
    connect_timeout : float
        Seconds for the connection (TCP, then the TLS handshake), within ``timeout``.
    retries : int
        Retries (0-10) of an answer 429 or 503 (busy: the server did not do the work), after the
        ``Retry-After`` it asks for (plus up to 20 % jitter), within ``timeout``; nothing else is
        retried (a refused connection, a timeout or a broken answer could double the cost or hide
        a fault). :class:`hevr.RemoteBusyError` when the server stays busy.
    transport : httpx.BaseTransport, optional
        The HTTP transport (tests: ``httpx.MockTransport``); then ``cafile`` is the transport's
        business and the deadline is checked between the chunks it gives. By default, one whose
        sockets obey the deadline (:mod:`hevr.remote.transport`).

    Returns
    -------
    Server
        ``server.stores()`` lists what it serves, ``server.open(name_or_id)`` gives a
        :class:`~hevr.remote.volume.RemoteVolume` for :func:`hevr.render` and friends.

    Raises
    ------
    RemoteError
        From the requests, typed: :class:`hevr.RemoteTimeoutError`, :class:`hevr.RemoteConnectError`,
        :class:`hevr.RemoteBusyError`, :class:`hevr.RemoteUnauthorisedError`,
        :class:`hevr.RemoteNotFoundError`, :class:`hevr.RemoteRefusedError`,
        :class:`hevr.RemoteAnswerError` (what the key holder's checks caught: a faulty or lying
        server), else a plain :class:`hevr.RemoteError` (a server failure).

    Examples
    --------
    ``rv = hevr.connect("https://render.example.org:8750", token=tok).open("ct")`` (the name
    ``hevr serve`` printed, or the store id),
    then ``hevr.render(rv, hevr.Camera.orbit(rv, azimuth=30))`` and ``img.decrypt(priv)``.
    """
    return Server(
        url,
        token=token,
        cafile=cafile,
        timeout=timeout,
        connect_timeout=connect_timeout,
        retries=retries,
        transport=transport,
    )


class Server(Connection):
    """A connection to ``hevr serve`` (:func:`connect`): its stores, :meth:`open`. Thread-safe for
    requests; close it (or use it as a context manager) to release its connections."""

    def __enter__(self) -> Server:
        return self

    def get_json(self, path: str, limit: int = MAX_BODY) -> dict[str, Any]:
        raw, _ = self.request("GET", path, limit=limit)
        return self._json(raw, f"GET {path}", limit)

    # -- the API --------------------------------------------------------------------
    def stores(self) -> list[dict[str, Any]]:
        """The stores this token may render: ``[{"id", "name", "shape", "channels", "tags", ...}]``
        (``shape`` in ``rv.shape``'s order, z, y, x, as :attr:`hevr.EncryptedVolume.shape`)
        summarised from each store's public metadata (checked as :meth:`open` checks it); ``name``:
        the name it is served under (None: by id only)."""
        return [
            {
                "id": sid,
                "name": name,
                "shape": tuple(meta.shape),
                "spacing": meta.spacing,
                "channels": [c for c in ("scalar", "vector", "gradient") if getattr(meta, c) is not None],
                "levels": len(meta.levels),
                "tags": bool(meta.tags),
                "fingerprint": meta.fingerprint,
            }
            for sid, name, meta in self.described()
        ]

    def described(self) -> list[tuple[str, str | None, Any]]:
        """(id, served name, checked :class:`~hevr.store.metadata.VolumeMetadata`) of every store this
        token may render (:func:`~hevr.remote.volume.parse_stores`)."""
        return parse_stores(self.get_json("/v1/stores", limit=MAX_STORES_BYTES), self.url)

    def open(self, name_or_id: str) -> RemoteVolume:
        """A :class:`~hevr.remote.volume.RemoteVolume` of the store served under ``name_or_id``.

        Parameters
        ----------
        name_or_id : str
            A store id (16 lower-case hex digits): that store, its path ``<url>/v1/stores/<id>``.
            Or the name ``hevr serve`` serves a store under: the volume's path is then
            ``<url>/v1/stores/<name>`` (what the key holder's known stores record, so that another
            version under the name is noticed), and every request names the id of the metadata
            checked here (pinned: a server that swaps the store later is refused).

        Returns
        -------
        RemoteVolume
        """
        if is_store_id(name_or_id):
            sid, meta = parse_description(self.get_json(f"/v1/stores/{name_or_id}"), self.url)
            if sid != name_or_id:
                raise RemoteAnswerError(
                    f"server {self.url}: expected the store {name_or_id}, got the description of {sid}"
                )
            return RemoteVolume(self, sid, meta)
        try:
            name = check_store_name(name_or_id, "name_or_id")
        except ParameterError:
            raise ParameterError(
                f"name_or_id: expected a store id (16 lower-case hex digits) or a store name (1-64 "
                f"letters, digits or _.@-), got {str(name_or_id)[:40]!r}"
            ) from None
        item = self.get_json(f"/v1/stores/{name}")
        sid, meta = parse_description(item, self.url)
        got = parse_name(item, self.url)
        if got != name:
            raise RemoteAnswerError(
                f"server {self.url}: expected the description of the store named {name!r}, got "
                f"{'one named ' + repr(got) if got else 'one without a name'} (store {sid})"
            )
        return RemoteVolume(self, sid, meta, name=name)
