"""The key holder's side of the wire: :func:`hevr.connect` and :class:`Server`.

Everything the server sends is untrusted data, read with bounds:

* every answer's size is bounded *before* it is read — by what the request implies for an image
  (H·W·K·record width, :func:`image_limit`), by :data:`~hevr.remote.protocol.MAX_BODY`-sized
  limits for JSON — and the bytes are counted as they arrive (a ``Content-Length`` that says more
  is refused unread);
* the raw bytes are read, never decompressed: an answer with a ``Content-Encoding`` is refused
  (a compression bomb cannot expand here);
* redirects are not followed (a server cannot send the token, or the request, elsewhere);
* one deadline (``timeout`` seconds) bounds a whole answer, so a server dribbling bytes cannot
  hold the caller longer;
* JSON is parsed strictly (:func:`~hevr.remote.protocol.parse_json`), images by the ``.hevr``
  parser, and nothing is ever unpickled.

Every failure — unreachable, TLS, timeout, a problem document, a malformed answer — is a
:class:`hevr.RemoteError` naming the server and what was expected; ``httpx``, ``ssl`` and
``json`` exceptions never reach the caller.
"""

from __future__ import annotations

import json
import logging
import ssl
import time
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx

from ..errors import HevrError, ParameterError, RemoteError
from .protocol import END, MAX_BODY, PROBLEM_MEDIA, UNITS_MEDIA, check_store_name, is_store_id, parse_json, unpack_head
from .volume import RemoteVolume, parse_description, parse_name

log = logging.getLogger(__name__)

__all__ = ["Server", "connect"]

MAX_STORES_BYTES = 16 * MAX_BODY  # the store list: a few KiB of metadata per store


def connect(url: str, token: str | None = None, cafile: str | None = None, timeout: float = 60.0) -> Server:
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
        Seconds for a whole answer (a render included).

    Returns
    -------
    Server
        ``server.stores()`` lists what it serves, ``server.open(name_or_id)`` gives a
        :class:`~hevr.remote.volume.RemoteVolume` for :func:`hevr.render` and friends.

    Examples
    --------
    ``rv = hevr.connect("https://render.example.org:8750", token=tok).open("ct")`` (the name
    ``hevr serve`` printed, or the store id),
    then ``hevr.render(rv, hevr.Camera.orbit(rv, azimuth=30))`` and ``img.decrypt(priv)``.
    """
    return Server(url, token=token, cafile=cafile, timeout=timeout)


class Server:
    """A connection to ``hevr serve`` (:func:`connect`). Thread-safe for requests; close it (or use
    it as a context manager) to release its connections."""

    def __init__(self, url: str, token: str | None = None, cafile: str | None = None,
                 timeout: float = 60.0) -> None:
        if not isinstance(url, str):
            raise ParameterError(f"url: expected 'http(s)://host:port', got {type(url).__name__}")
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname or parts.query or parts.fragment:
            raise ParameterError(f"url: expected 'http(s)://host[:port]', got {url[:100]!r}")
        if parts.username or parts.password:
            raise ParameterError("url: expected no user or password in the URL (pass token=)")
        if token is not None and (not isinstance(token, str) or not token or not token.isprintable()
                                  or len(token) > 4096 or any(c.isspace() for c in token)):
            raise ParameterError("token: expected the server's bearer token (printable, no spaces)")
        if not isinstance(timeout, (int, float)) or isinstance(timeout, bool) or not 0 < timeout <= 86400:
            raise ParameterError(f"timeout: expected seconds in (0, 86400], got {timeout!r}")
        if cafile is not None and parts.scheme != "https":
            raise ParameterError("cafile: expected an https:// url with a CA file, got an http:// url")
        verify: Any = True
        if cafile is not None:
            try:
                verify = ssl.create_default_context(cafile=str(cafile))
            except (OSError, ssl.SSLError) as exc:
                raise ParameterError(f"cafile: expected a PEM CA bundle, got {str(cafile)[:100]!r} "
                                     f"({type(exc).__name__})") from None
        self.url = url.rstrip("/")
        self.timeout = float(timeout)
        self._token = token
        headers = {"Accept-Encoding": "identity", "User-Agent": "hevr"}
        self._http = httpx.Client(base_url=self.url, headers=headers, verify=verify, follow_redirects=False,
                                  timeout=httpx.Timeout(self.timeout), trust_env=False)

    def __repr__(self) -> str:  # never the token
        return f"Server({self.url!r})"

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Server:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- requests -------------------------------------------------------------------
    def _headers(self, accept: str) -> dict:
        h = {"Accept": f"{accept}, {PROBLEM_MEDIA}"}
        if self._token is not None:
            h["Authorization"] = f"Bearer {self._token}"
        return h

    def request(self, method: str, path: str, *, body: dict | None = None, accept: str = "application/json",
                limit: int = MAX_BODY) -> tuple[bytes, dict]:
        """One request; the answer's bytes (at most ``limit``) and headers, or a RemoteError."""
        (answer,) = list(self._exchange(method, path, body, accept, limit, frames=False))
        return answer

    def frames(self, path: str, body: dict, limit: int) -> Iterator[tuple[int, bytes]]:
        """The frames (index, bytes) of a units stream, each as it arrives, then (END, the end
        frame's JSON object), checked here: a problem there is a RemoteError."""
        for index, data in self._exchange("POST", path, body, UNITS_MEDIA, limit, frames=True):
            if index == END:
                status = self._json(data, "the stream's end")
                if status.get("ok") is not True:
                    raise self._problem(200, status, "a finished stream")
                yield END, status
                return
            yield index, data
        raise RemoteError(f"server {self.url}: expected the stream's end frame, got the end of the answer")

    def _exchange(self, method: str, path: str, body: dict | None, accept: str, limit: int,
                  frames: bool) -> Iterator[Any]:
        content = None if body is None else json.dumps(body, separators=(",", ":")).encode()
        headers = self._headers(accept)
        if content is not None:
            headers["Content-Type"] = "application/json"
        deadline = time.monotonic() + self.timeout
        what = f"{method} {path}"
        try:
            with self._http.stream(method, path, content=content, headers=headers) as r:
                status = r.status_code
                encoding = r.headers.get("content-encoding", "identity").strip().lower()
                if encoding not in ("", "identity"):
                    raise RemoteError(f"server {self.url}: {what}: expected an answer without Content-Encoding, "
                                      f"got {encoding[:40]!r} (refused unread)", status=status)
                if 300 <= status < 400:
                    raise RemoteError(f"server {self.url}: {what}: expected an answer, got a redirect (HTTP "
                                      f"{status}) to {r.headers.get('location', '?')[:100]!r}, not followed",
                                      status=status)
                media = r.headers.get("content-type", "").split(";")[0].strip().lower()
                if status != 200:
                    raw = self._read(r, MAX_BODY, deadline, what)
                    doc = None
                    if media in (PROBLEM_MEDIA, "application/json"):
                        try:
                            doc = parse_json(raw, "problem")
                        except HevrError:
                            doc = None
                    raise self._problem(status, doc, what)
                if media != accept:
                    raise RemoteError(f"server {self.url}: {what}: expected {accept}, got {media[:60]!r}",
                                      status=status)
                declared = r.headers.get("content-length")
                if declared is not None and (not declared.isdigit() or int(declared) > limit):
                    raise RemoteError(f"server {self.url}: {what}: expected at most {limit} bytes, got "
                                      f"Content-Length {declared[:20]} (refused unread)", status=status)
                if not frames:
                    yield self._read(r, limit, deadline, what), dict(r.headers)
                    return
                yield from self._frames(r, limit, deadline, what)
        except RemoteError:
            raise
        except (httpx.HTTPError, ssl.SSLError, OSError, ValueError) as exc:
            kind = "timed out" if isinstance(exc, httpx.TimeoutException) else type(exc).__name__
            raise RemoteError(f"server {self.url}: {what}: {kind}: {str(exc)[:200]}") from None

    def _read(self, r: Any, limit: int, deadline: float, what: str) -> bytes:
        buf = bytearray()
        for chunk in r.iter_raw():
            buf += chunk
            if len(buf) > limit:
                raise RemoteError(f"server {self.url}: {what}: expected at most {limit} bytes, got more "
                                  "(the rest refused unread)", status=r.status_code)
            if time.monotonic() > deadline:
                raise RemoteError(f"server {self.url}: {what}: timed out after {self.timeout:g} s (slow answer)")
        return bytes(buf)

    def _frames(self, r: Any, limit: int, deadline: float, what: str) -> Iterator[tuple[int, bytes]]:
        buf = bytearray()
        total = 0
        for chunk in r.iter_raw():
            total += len(chunk)
            if total > limit:
                raise RemoteError(f"server {self.url}: {what}: expected at most {limit} bytes of units, got more")
            if time.monotonic() > deadline:
                raise RemoteError(f"server {self.url}: {what}: timed out after {self.timeout:g} s (slow stream)")
            buf += chunk
            while len(buf) >= 8:
                index, length = unpack_head(bytes(buf[:8]))
                if length > limit:
                    raise RemoteError(f"server {self.url}: {what}: a frame of {length} bytes (at most {limit})")
                if len(buf) < 8 + length:
                    break
                data = bytes(buf[8:8 + length])
                del buf[:8 + length]
                yield index, data
                if index == END:
                    if buf:
                        raise RemoteError(f"server {self.url}: {what}: expected nothing after the end frame")
                    return
        if buf:
            raise RemoteError(f"server {self.url}: {what}: the stream ended inside a frame (truncated)")

    def _json(self, raw: bytes, what: str, limit: int = MAX_BODY) -> dict:
        try:
            doc = parse_json(raw, what, limit)
        except HevrError as exc:
            raise RemoteError(f"server {self.url}: {exc}") from None
        if not isinstance(doc, dict):
            raise RemoteError(f"server {self.url}: {what}: expected a JSON object, got {type(doc).__name__}")
        return doc

    def _problem(self, status: int, doc: Any, what: str) -> RemoteError:
        detail = title = None
        if isinstance(doc, dict):
            detail = doc.get("detail") if isinstance(doc.get("detail"), str) else None
            title = doc.get("title") if isinstance(doc.get("title"), str) else None
        text = "; ".join(x[:500] for x in (title, detail) if x) or "no problem document"
        clean = "".join(c if c.isprintable() else "?" for c in text)
        return RemoteError(f"server {self.url}: {what}: HTTP {status}: {clean}", status=status,
                           problem=doc if isinstance(doc, dict) else None)

    def get_json(self, path: str, limit: int = MAX_BODY) -> dict:
        raw, _ = self.request("GET", path, limit=limit)
        return self._json(raw, f"GET {path}", limit)

    # -- the API --------------------------------------------------------------------
    def stores(self) -> list[dict]:
        """The stores this token may render: ``[{"id", "name", "shape", "channels", "tags", ...}]``
        summarised from each store's public metadata (checked as :meth:`open` checks it); ``name``:
        the name it is served under (None: by id only)."""
        doc = self.get_json("/v1/stores", limit=MAX_STORES_BYTES)
        items = doc.get("stores")
        if not isinstance(items, list):
            raise RemoteError(f"server {self.url}: GET /v1/stores: expected a 'stores' list")
        out = []
        for item in items:
            sid, meta = parse_description(item, self.url)
            out.append({"id": sid, "name": parse_name(item, self.url), "shape": tuple(meta.shape[::-1]),
                        "spacing": meta.spacing,
                        "channels": [c for c in ("scalar", "vector", "gradient") if getattr(meta, c) is not None],
                        "levels": len(meta.levels), "tags": bool(meta.tags), "fingerprint": meta.fingerprint})
        return out

    def open(self, name_or_id: str) -> Any:
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
                raise RemoteError(f"server {self.url}: expected the store {name_or_id}, got the description of {sid}")
            return RemoteVolume(self, sid, meta)
        try:
            name = check_store_name(name_or_id, "name_or_id")
        except ParameterError:
            raise ParameterError(f"name_or_id: expected a store id (16 lower-case hex digits) or a store name (1-64 "
                                 f"letters, digits or _.@-), got {str(name_or_id)[:40]!r}") from None
        item = self.get_json(f"/v1/stores/{name}")
        sid, meta = parse_description(item, self.url)
        got = parse_name(item, self.url)
        if got != name:
            raise RemoteError(f"server {self.url}: expected the description of the store named {name!r}, got "
                              f"{'one named ' + repr(got) if got else 'one without a name'} (store {sid})")
        return RemoteVolume(self, sid, meta, name=name)
