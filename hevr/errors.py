"""The hevr error hierarchy.

Every error raised on purpose by hevr derives from :class:`HevrError`, so callers can
catch everything hevr-specific with one ``except``. Several classes also derive from the
matching builtin (``ValueError``, ``OverflowError``, ``ImportError``) so generic code
keeps working.

Messages name the parameter, what was expected and what came. They never contain
secret-key material (p, q, lambda, mu, or anything derived from them).
"""

from __future__ import annotations

import errno
import os
from typing import Any

__all__ = [
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
    "IntegrityError",
    "VerificationError",
    "FrameMovedWarning",
    "VolumeFormatError",
    "CorruptVolumeError",
    "MissingDependencyError",
    "MissingFileError",
    "MemoryLimitError",
    "ExistingFileError",
    "NotRegularFileError",
    "FileSystemError",
    "RemoteError",
    "RemoteTimeoutError",
    "RemoteConnectError",
    "RemoteBusyError",
    "RemoteUnauthorisedError",
    "RemoteNotFoundError",
    "RemoteRefusedError",
    "RemoteAnswerError",
    "ForeignClusterError",
    "InsecureKeyWarning",
    "KeyFilePermissionWarning",
]


class HevrError(Exception):
    """Base class of every error hevr raises on purpose."""


class ParameterError(HevrError, ValueError):
    """An argument has the wrong type, shape or value."""


class InvalidKeyError(HevrError, ValueError):
    """A key (or key file) is malformed, inconsistent or tampered with."""


class KeyMismatchError(HevrError, ValueError):
    """Data was encrypted under a key with another fingerprint."""


class PlaintextOverflowError(HevrError, OverflowError):
    """A decrypted value lies in the ambiguous middle band of Z_n (``|m| >= n/3``)."""


class RenderPlanError(HevrError, ValueError):
    """The overflow planner refused a render whose mantissas could exceed n/3."""


class MemoryLimitError(HevrError, MemoryError):
    """A resident volume would take more of a worker's memory than ``hevr.limits.resident-memory``
    allows; refused before anything is loaded."""


class StoreError(HevrError):
    """Problem with an encrypted volume or image store."""


class StoreExistsError(StoreError, FileExistsError):
    """The target store exists and ``overwrite=True`` was not given."""


class IncompleteStoreError(StoreError):
    """The store was not finished (some bricks are missing)."""


class CorruptStoreError(StoreError):
    """The store is foreign, of another format version, truncated or holds invalid ciphertexts."""


class IntegrityError(HevrError, ValueError):
    """Data failed an integrity check: a decrypted value outside the range its render plan
    allows, or an image file whose checksum does not match. The data was corrupted (or
    mixed up) somewhere between encryption and decryption; no image is returned."""


class VerificationError(IntegrityError):
    """A verified render failed its check: the image's ray sums are not the ones the store's
    linearly homomorphic tags certify (:mod:`hevr.rendering.verify`) — an altered, substituted or
    replayed image or store, or a server that did not render as asked. No image is returned."""


class VolumeFormatError(HevrError, ValueError):
    """A volume file or array cannot be read or is not a valid 3-D volume."""


class CorruptVolumeError(VolumeFormatError):
    """A volume file of a kind hevr reads whose data fails: fewer bytes than its header
    declares, or pixel data that neither decodes nor is refused for a plugin known to be
    missing. The data failed, not the request (the CLI exits 1 for it, 2 for other
    :class:`VolumeFormatError`)."""


class MissingDependencyError(HevrError, ImportError):
    """An optional dependency (an extra) is needed but not installed."""


class MissingFileError(HevrError, FileNotFoundError):
    """A file, folder or store that should exist does not: the one error hevr raises for a
    missing path, everywhere (also a :class:`FileNotFoundError`).

    >>> str(MissingFileError("key", "a key file", "k.json"))
    'key: expected a key file, found nothing at k.json'
    """

    def __init__(self, name: str, expected: str, path: str | os.PathLike[str]) -> None:
        super().__init__(errno.ENOENT, f"{name}: expected {expected}, found nothing at {path}", str(path))

    def __str__(self) -> str:
        return str(self.strerror)


class ExistingFileError(HevrError, FileExistsError):
    """A file that would be written exists already and replacing it was not asked for (also
    a :class:`FileExistsError`).

    >>> str(ExistingFileError("path", "k.json"))
    'path: expected no file at k.json (pass overwrite=True to replace it), found one'
    """

    def __init__(self, name: str, path: str | os.PathLike[str]) -> None:
        super().__init__(
            errno.EEXIST,
            f"{name}: expected no file at {path} (pass overwrite=True to replace it), found one",
            str(path),
        )

    def __str__(self) -> str:
        return str(self.strerror)


class NotRegularFileError(HevrError, OSError):
    """A path that should be a regular file is something else: a folder, a FIFO, a socket, a
    device (reading a FIFO or a device would block or never end, so readers refuse them before
    opening them for reading). Also an :class:`OSError` (errno ``EINVAL``).

    >>> str(NotRegularFileError("path", "an encrypted image file", "a.hevr", "a FIFO"))
    'path: expected an encrypted image file (a regular file), got a FIFO at a.hevr'
    """

    def __init__(self, name: str, expected: str, path: str | os.PathLike[str], kind: str) -> None:
        super().__init__(errno.EINVAL, f"{name}: expected {expected} (a regular file), got {kind} at {path}", str(path))

    def __str__(self) -> str:
        return str(self.strerror)


class FileSystemError(HevrError, OSError):
    """The operating system refused a file operation hevr needed: disk full (``ENOSPC``), file
    too large (``EFBIG``), read-only filesystem (``EROFS``), name too long, not a folder,
    permission denied, … Also an :class:`OSError` with the original ``errno`` and
    ``filename``; the message names what was being done, the path and the reason.

    >>> e = FileSystemError(errno.ENOSPC, "writing the image", "/d/a.hevr")
    >>> str(e), e.errno == errno.ENOSPC, e.filename
    ('writing the image /d/a.hevr: No space left on device (ENOSPC)', True, '/d/a.hevr')
    """

    def __init__(self, err: int | None, doing: str, path: str | os.PathLike[str], reason: str | None = None) -> None:
        reason = reason or (os.strerror(err) if err else "failed")
        code = errno.errorcode.get(err or 0)
        text = f"{doing} {path}: {reason}" + (f" ({code})" if code else "")
        super().__init__(err, text, str(path))

    def __str__(self) -> str:
        return str(self.strerror)


class RemoteError(HevrError, ConnectionError):
    """A render server (``hevr serve``, :func:`hevr.connect`) failed, refused the request or sent
    something that is not a valid answer: unreachable, timed out, a TLS failure, an error document,
    a forged, truncated, oversized or compressed answer. ``status`` is the HTTP status (None when
    none came) and ``problem`` the server's RFC 9457 problem document, parsed as data (or None).
    Typed by cause (issue 48): :class:`RemoteTimeoutError`, :class:`RemoteConnectError`,
    :class:`RemoteBusyError`, :class:`RemoteUnauthorisedError`, :class:`RemoteNotFoundError`,
    :class:`RemoteRefusedError`, :class:`RemoteAnswerError` (an answer the key holder's checks
    refused); this class itself for a server failure (HTTP 500) or a redirect.

    >>> str(RemoteError("server: expected an image, got HTTP 503 (busy)", status=503))
    'server: expected an image, got HTTP 503 (busy)'
    """

    def __init__(self, message: str, *, status: int | None = None, problem: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.problem = problem


class RemoteTimeoutError(RemoteError, TimeoutError):
    """No answer (or no connection) came from the render server within the caller's deadline:
    ``timeout`` seconds for the whole exchange (connecting, the answer's head and body, waits
    before a retry), ``connect_timeout`` for the connection. The key holder's decryption is not
    counted. The server may be busy, slow or gone; nothing it sent was taken. Also a
    :class:`TimeoutError`.

    >>> isinstance(RemoteTimeoutError("server: timeout: expected an answer within 2 s, got none"), TimeoutError)
    True
    """


class RemoteConnectError(RemoteError):
    """No HTTP exchange could be made with the render server: the connection was refused, the name
    did not resolve, the TLS handshake failed (a certificate this process does not trust: pass
    ``cafile=``; ``http://`` to a TLS port or ``https://`` to a plain one: the message says which
    scheme), or the server closed the connection without an answer."""


class RemoteBusyError(RemoteError):
    """The render server is busy (HTTP 429 or 503) and stayed busy through the bounded retries, or
    asked to wait longer than the deadline leaves; ``retry_after`` is the seconds it asked for
    (None: it named none). Nothing is wrong with the request or the server's honesty: try later.

    >>> e = RemoteBusyError("server: HTTP 429: too many renders", status=429, retry_after=1.0)
    >>> e.status, e.retry_after
    (429, 1.0)
    """

    def __init__(
        self,
        message: str,
        *,
        status: int | None = None,
        problem: dict[str, Any] | None = None,
        retry_after: float | None = None,
    ) -> None:
        super().__init__(message, status=status, problem=problem)
        self.retry_after = retry_after


class RemoteUnauthorisedError(RemoteError, PermissionError):
    """The render server refused the token (HTTP 401, or 403): none was sent (pass ``token=``; the
    CLI reads ``HEVR_TOKEN``) or it is not one of the server's. Also a :class:`PermissionError`."""


class RemoteNotFoundError(RemoteError, LookupError):
    """The render server serves no store under that name or id, or not to this token (HTTP 404:
    the server does not tell the two apart). Also a :class:`LookupError`."""


class RemoteRefusedError(RemoteError, ValueError):
    """The render server refused the request as asked (HTTP 400, 405, 413, 415 or 422: malformed,
    too large, or refused by its render planner: a larger step or a smaller image may do). Also a
    :class:`ValueError`."""


class RemoteAnswerError(RemoteError, IntegrityError):
    """The render server's answer is not a valid answer to the request — what the key holder's
    checks caught: malformed, truncated, oversized, compressed, of another media type, another
    store or another render, a header field other than the request implies, a value that is not
    a ciphertext, a malformed aggregate. A faulty or lying server; no image is returned. Both a
    :class:`RemoteError` and an :class:`IntegrityError`. (A verified image whose ray sums fail
    their tags is refused at decryption with :class:`VerificationError`, remote or not.)

    >>> isinstance(RemoteAnswerError("server: the image's 'shape' is not the one asked for"), IntegrityError)
    True
    """


class ForeignClusterError(HevrError, PermissionError):
    """A private key was about to be used while this process is a Dask client of a cluster it did not
    start and that was not declared its own (:func:`hevr.own_cluster`, ``$HEVR_OWN_CLUSTER``). Dask
    unpickles what a cluster sends, so that cluster's scheduler and workers could run code where the
    key is. Refused before the key is used; the message names the scheduler and the two ways out:
    :func:`hevr.connect` to another party's ``hevr serve`` (data only), or :func:`hevr.own_cluster`
    for a cluster that is yours. Also a :class:`PermissionError`.

    >>> str(ForeignClusterError("client: expected a cluster of this process's own, got tcp://h:8786"))
    "client: expected a cluster of this process's own, got tcp://h:8786"
    """


class FrameMovedWarning(UserWarning):
    """A verified frame was read from another place than the key holder saved it: it proves its
    store and view (:mod:`hevr.image.proof`), not that it belongs where it was found; decrypt with
    ``require_verified=hevr.Expect(store=..., view=...)`` to check that it is the frame you expect."""


class InsecureKeyWarning(UserWarning):
    """A key shorter than 2048 bits was generated or loaded."""


class KeyFilePermissionWarning(UserWarning):
    """A private key file is readable or writable by its group or by others (as OpenSSH's
    "UNPROTECTED PRIVATE KEY FILE!"); the message says ``chmod 600 PATH``. A warning, not
    a refusal: python-paillier's ``pheutil`` writes its keys with the umask's mode (0644),
    and some filesystems (mounted Windows drives, some network shares) cannot hold 0600."""
