"""A store served by ``hevr serve``, as the key holder sees it: :class:`RemoteVolume`.

It is an :class:`hevr.EncryptedVolume` without a path to read: its public metadata came from the
server (parsed by :meth:`hevr.store.metadata.VolumeMetadata.from_dict`, the same strict parser
that opens a local store), so everything the key holder computes from public data — cameras
(:meth:`hevr.Camera.orbit`), planes, error bounds, the render plan, the image's every public
field — is computed here, in the key holder's process, and the server's answer must match it.
:func:`hevr.render`, :func:`hevr.render_slice`, :func:`hevr.render_frame` and :class:`hevr.Viewer`
take it as they take a local volume and send the request to the server
(:mod:`hevr.remote.render`); the frames are the in-process ones, byte for byte.

Opened by name (``server.open("ct")``, the name ``hevr serve`` gives the store), its
:attr:`~RemoteVolume.path` is ``<server>/v1/stores/<name>``: the name the owner controls, which the
key holder's known stores (:mod:`hevr.store.known`) record, so that another version served under
that name later is noticed. Every request goes to :attr:`~RemoteVolume.store_id`, the id of the
metadata checked at opening (pinned for the session). Opened by id, the path names the id.

It holds no brick: :meth:`persist` and brick reads are refused (the server decides residency:
``hevr serve --persist``).
"""

from __future__ import annotations

from typing import Any

from ..crypto.keys import PublicKey
from ..errors import CorruptStoreError, ParameterError, RemoteAnswerError
from ..store.metadata import VolumeMetadata
from ..store.reader import EncryptedVolume
from ..volume.pyramid import check_level
from . import schema
from .failures import check_answer
from .packed import render_remote_packed, render_remote_packed_slice
from .protocol import check_store_name
from .render import render_remote

__all__ = ["RemoteVolume", "parse_description", "parse_name", "parse_stores"]

MAX_N_DIGITS = 1300  # a 4096-bit modulus has 1234 decimal digits


def parse_name(item: Any, url: str) -> str | None:
    """The served name of a store description (None: the server gave none, as servers before
    issue 47 did, or serves it by id only); :class:`hevr.RemoteAnswerError` for one that is not a name."""
    name = item.get("name") if isinstance(item, dict) else None
    if name is None:
        return None
    try:
        return check_store_name(name, f"server {url}: a store description: name")
    except ParameterError as exc:
        raise RemoteAnswerError(str(exc)) from None


def parse_description(item: Any, url: str) -> tuple[str, VolumeMetadata]:
    """(store id, metadata) of a store description ``{"id", "name", "metadata"}`` from the server,
    checked by :class:`hevr.remote.schema.Store` (``name`` may be absent: servers before issue 47
    sent none; :func:`parse_name`) and then the metadata by its own strict parser;
    :class:`hevr.RemoteAnswerError` naming what is wrong."""
    if isinstance(item, dict) and "name" not in item:
        item = {**item, "name": None}
    parse_name(item, url)  # in a name's own words, and not one that reads as a store id
    wire = check_answer(schema.Store, item, url, "a store description")
    sid, raw = wire.id, wire.metadata
    pk = raw.get("public_key")
    if not (isinstance(pk, dict) and isinstance(pk.get("n"), str) and 0 < len(pk["n"]) <= MAX_N_DIGITS):
        raise RemoteAnswerError(
            f"server {url}: store {sid}: n: expected a modulus of at most {MAX_N_DIGITS} decimal digits"
        )
    try:
        meta = VolumeMetadata.from_dict(raw, where=f"server {url}: store {sid}")
    except CorruptStoreError as exc:
        raise RemoteAnswerError(str(exc)) from None
    except (ValueError, TypeError, OverflowError) as exc:
        raise RemoteAnswerError(f"server {url}: store {sid}: metadata: {type(exc).__name__}") from None
    if meta.store_id != sid:
        raise RemoteAnswerError(f"server {url}: store {sid}: its metadata names the store {meta.store_id}")
    if not meta.complete:
        raise RemoteAnswerError(f"server {url}: store {sid}: expected a complete store, got an incomplete one")
    try:
        if PublicKey(int(meta.n)).fingerprint != meta.fingerprint:
            raise RemoteAnswerError(f"server {url}: store {sid}: the key fingerprint does not match the modulus n")
    except (ValueError, ParameterError) as exc:
        raise RemoteAnswerError(f"server {url}: store {sid}: n: {exc}") from None
    return sid, meta


def parse_stores(doc: Any, url: str) -> list[tuple[str, str | None, VolumeMetadata]]:
    """(id, served name, metadata) of every store of a store list ``{"stores": [...]}`` (``GET
    /v1/stores``, :class:`hevr.remote.schema.Stores`), each description checked by
    :func:`parse_description`; :class:`hevr.RemoteAnswerError` naming what is wrong."""
    items = doc.get("stores") if isinstance(doc, dict) else None
    if isinstance(items, list):
        doc = {**doc, "stores": [{**i, "name": None} if isinstance(i, dict) and "name" not in i else i for i in items]}
    check_answer(schema.Stores, doc, url, "GET /v1/stores")
    out = []
    for item in doc["stores"]:
        sid, meta = parse_description(item, url)
        out.append((sid, parse_name(item, url), meta))
    return out


class RemoteVolume(EncryptedVolume):
    """A store on a render server (:meth:`hevr.remote.client.Server.open`).

    Parameters
    ----------
    server : Server
        The connection it renders on.
    store_id : str
        The id every request names (the checked metadata's).
    meta : VolumeMetadata
        Its public metadata (of ``level``; ``base``: level 0's).
    name : str, optional
        The served name it was opened by: its :attr:`path` is then ``<server>/v1/stores/<name>``
        (module docstring); None: opened by id.
    """

    def __init__(
        self,
        server: Any,
        store_id: str,
        meta: VolumeMetadata,
        level: int = 0,
        base: VolumeMetadata | None = None,
        name: str | None = None,
    ) -> None:
        super().__init__(f"{server.url}/v1/stores/{name or store_id}", meta, level, base)
        self.server = server
        self.store_id = store_id
        self.name = name

    @property
    def remote(self) -> Any:
        """The server this volume is rendered on."""
        return self.server

    def __repr__(self) -> str:
        return f"RemoteVolume({self.path!r}, shape={self.shape}, brick={self.brick}, key={self.meta.fingerprint[:16]}…)"

    def __getstate__(self) -> dict:
        raise TypeError("a RemoteVolume is not pickled: it holds a connection (open it again with hevr.connect)")

    def at_level(self, level: int) -> RemoteVolume:
        base = self.base if self.level and self.base is not None else self.meta  # a level's base: level 0's
        ev0 = self if not self.level else RemoteVolume(self.server, self.store_id, base, name=self.name)
        level = check_level(level, ev0.levels)
        if level == 0:
            return RemoteVolume(self.server, self.store_id, base, name=self.name)
        return RemoteVolume(self.server, self.store_id, base.level_meta(level), level, base, name=self.name)

    def render_request(self, view: Any, spec: Any, **kwargs: Any) -> Any:
        """:func:`hevr.render`'s work on this volume (:func:`hevr.remote.render.render_remote`):
        the rendering layer hands a checked request here rather than importing the client."""
        return render_remote(self, view, spec, **kwargs)

    def render_packed_request(self, camera: Any, sampling: str, **kwargs: Any) -> Any:
        """A packed store's frame on the server (:func:`hevr.remote.packed.render_remote_packed`)."""
        return render_remote_packed(self, camera, sampling, **kwargs)

    def render_packed_slice_request(self, plane: Any, sampling: str, **kwargs: Any) -> Any:
        """A packed store's slice on the server (:func:`hevr.remote.packed.render_remote_packed_slice`)."""
        return render_remote_packed_slice(self, plane, sampling, **kwargs)

    def _plain(self) -> RemoteVolume:
        return self

    def persist(self, channels: Any = None, *, client: Any = None, backend: str | None = None) -> EncryptedVolume:
        raise ParameterError(
            "persist: expected a local volume; a remote store's residency is the server's (hevr serve --persist)"
        )

    def read_brick_bytes(self, *args: Any, **kwargs: Any) -> Any:
        raise ParameterError("read_brick_bytes: a remote volume's bricks stay on the server")

    def read_brick(self, *args: Any, **kwargs: Any) -> Any:
        raise ParameterError("read_brick: a remote volume's bricks stay on the server")

    def verify(self, coprime: bool = True) -> None:
        raise ParameterError("verify: a remote store is checked by the server that reads it")
