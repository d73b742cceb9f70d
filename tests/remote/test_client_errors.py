"""The key holder's client tells failures apart (issue 48): every HTTP error status is a typed
:class:`hevr.RemoteError` (busy, unauthorised, not found, refused, a server failure), an answer the
checks refuse is a :class:`hevr.RemoteAnswerError`, a busy server is retried a bounded number of
times after its ``Retry-After``; all in process, through ``httpx.MockTransport``."""

from __future__ import annotations

import json
import time

import httpx
import pytest

import hevr
from hevr.remote import connect
from hevr.remote.failures import retry_after

URL = "http://render.test:8750"
PROBLEM = "application/problem+json"


def problem(status, title="x", detail="y", headers=None):
    return httpx.Response(
        status,
        headers={"Content-Type": PROBLEM, **(headers or {})},
        content=json.dumps({"title": title, "status": status, "detail": detail}).encode(),
    )


def stores_ok():
    return httpx.Response(200, headers={"Content-Type": "application/json"}, content=b'{"stores": []}')


class Script:
    """A MockTransport handler answering from a list (the last answer repeats); counts the calls."""

    def __init__(self, *answers):
        self.answers = list(answers)
        self.calls = []

    def __call__(self, request):
        self.calls.append((time.monotonic(), request))
        answer = self.answers[min(len(self.calls) - 1, len(self.answers) - 1)]
        if isinstance(answer, Exception):
            raise answer
        return answer() if callable(answer) else answer


def server(script, **kw):
    return connect(URL, transport=httpx.MockTransport(script), **kw)


@pytest.mark.parametrize(
    "status, cls, builtin, words",
    [
        (401, hevr.RemoteUnauthorisedError, PermissionError, "no token was sent: set HEVR_TOKEN"),
        (403, hevr.RemoteUnauthorisedError, PermissionError, "pass token="),
        (404, hevr.RemoteNotFoundError, LookupError, "HTTP 404"),
        (400, hevr.RemoteRefusedError, ValueError, "HTTP 400"),
        (413, hevr.RemoteRefusedError, ValueError, "HTTP 413"),
        (422, hevr.RemoteRefusedError, ValueError, "HTTP 422: x; y"),
    ],
)
def test_statuses_are_typed(status, cls, builtin, words):
    script = Script(problem(status))
    with pytest.raises(cls, match=words) as e:
        server(script).stores()
    assert isinstance(e.value, builtin) and isinstance(e.value, hevr.RemoteError)
    assert not isinstance(e.value, hevr.RemoteAnswerError)
    assert e.value.status == status and e.value.problem["status"] == status
    assert len(script.calls) == 1  # never retried


def test_a_refused_token_is_told_apart_from_a_missing_one():
    with pytest.raises(hevr.RemoteUnauthorisedError, match="the token was not accepted: check HEVR_TOKEN"):
        server(Script(problem(401)), token="tok-wrong").stores()
    script = Script(problem(401))
    with pytest.raises(hevr.RemoteUnauthorisedError):
        server(script, token="tok-right").stores()
    assert script.calls[0][1].headers["authorization"] == "Bearer tok-right"


def test_a_server_failure_is_a_plain_remote_error():
    with pytest.raises(hevr.RemoteError, match="HTTP 500: x; y") as e:
        server(Script(problem(500))).stores()
    assert type(e.value) is hevr.RemoteError


def test_busy_then_ok_succeeds_after_one_retry():
    script = Script(problem(429, "too many concurrent renders", headers={"Retry-After": "1"}), stores_ok)
    t0 = time.monotonic()
    assert server(script, timeout=30).stores() == []
    assert len(script.calls) == 2
    assert script.calls[1][0] - script.calls[0][0] >= 1.0  # Retry-After honoured (never earlier)
    assert time.monotonic() - t0 < 15


def test_a_render_request_is_retried_too():
    script = Script(
        problem(503, "server out of memory", headers={"Retry-After": "0"}),
        lambda: httpx.Response(200, headers={"Content-Type": "application/json"}, content=b'{"a": 1}'),
    )
    raw, _ = server(script).request("POST", "/v1/stores/0123456789abcdef/render", body={"x": 1})
    assert raw == b'{"a": 1}' and len(script.calls) == 2
    assert script.calls[0][1].content == script.calls[1][1].content == b'{"x":1}'


def test_busy_forever_is_a_busy_error_after_the_cap():
    script = Script(problem(503, "server out of memory", headers={"Retry-After": "0.2"}))  # not an int: unreadable
    t0 = time.monotonic()
    with pytest.raises(hevr.RemoteBusyError, match="busy through 3 tries.*retry later") as e:
        server(script, timeout=30).stores()
    assert len(script.calls) == 3 and e.value.status == 503 and e.value.retry_after is None
    assert time.monotonic() - t0 < 20  # backoff 0.5 s, 1 s (x 0.5-1.5)

    script = Script(problem(429, headers={"Retry-After": "1"}))
    with pytest.raises(hevr.RemoteBusyError, match="asks to retry after 1 s") as e:
        server(script, retries=0).stores()
    assert len(script.calls) == 1 and e.value.retry_after == 1.0 and e.value.status == 429


def test_a_wait_beyond_the_deadline_is_not_waited():
    script = Script(problem(429, headers={"Retry-After": "3600"}))
    t0 = time.monotonic()
    with pytest.raises(hevr.RemoteBusyError) as e:
        server(script, timeout=5).stores()
    assert len(script.calls) == 1 and e.value.retry_after == 3600.0
    assert time.monotonic() - t0 < 4


def test_failures_without_an_answer():
    request = httpx.Request("GET", URL)
    with pytest.raises(hevr.RemoteTimeoutError, match="expected a connection within 7 s") as e:
        server(Script(httpx.ConnectTimeout("slow", request=request)), connect_timeout=7).stores()
    assert isinstance(e.value, TimeoutError)
    with pytest.raises(hevr.RemoteTimeoutError, match="expected an answer within 9 s.*decryption is not counted"):
        server(Script(httpx.ReadTimeout("slow", request=request)), timeout=9).stores()
    with pytest.raises(hevr.RemoteConnectError, match="ConnectError"):
        server(Script(httpx.ConnectError("refused", request=request))).stores()
    for bad in ({"connect_timeout": 0}, {"retries": -1}, {"retries": 11}, {"retries": True}, {"transport": object()}):
        with pytest.raises(hevr.ParameterError, match=next(iter(bad))):
            connect(URL, **bad)


@pytest.mark.parametrize(
    "answer, words",
    [
        (httpx.Response(200, headers={"Content-Type": "text/html"}, content=b"<html>"), "expected application/json"),
        (httpx.Response(200, headers={"Content-Type": "application/json"}, content=b"[]"), "JSON object"),
        (
            httpx.Response(200, headers={"Content-Type": "application/json", "Content-Encoding": "gzip"}, content=b"x"),
            "Content-Encoding",
        ),
        (httpx.Response(200, headers={"Content-Type": "application/json"}, content=b" " * (2 << 20)), "at most"),
    ],
)
def test_answers_the_checks_refuse_are_answer_errors(answer, words):
    with pytest.raises(hevr.RemoteAnswerError, match=words) as e:
        server(Script(answer)).stores()
    assert isinstance(e.value, hevr.IntegrityError) and isinstance(e.value, hevr.RemoteError)


def test_a_redirect_to_https_says_use_https():
    answer = httpx.Response(301, headers={"Location": "https://render.test:8750/v1/stores"})
    with pytest.raises(hevr.RemoteError, match="not followed \\(use https://render.test:8750\\)"):
        server(Script(answer)).stores()


def test_slow_chunks_hit_the_deadline_but_the_callers_time_between_frames_does_not():
    from hevr.remote.protocol import END, UNITS_MEDIA, pack_frame

    def units(delay):
        def body():
            for i in range(3):
                time.sleep(delay)
                yield pack_frame(i, b"\1" * 8)
            yield pack_frame(END, b'{"ok": true}')

        return lambda: httpx.Response(200, headers={"Content-Type": UNITS_MEDIA}, content=body())

    got = []
    for index, _ in server(Script(units(0.0)), timeout=1).frames("/v1/stores/x/stream", {}, 1 << 20):
        got.append(index)
        time.sleep(0.5)  # the key holder decrypting: 2 s in all, not counted
    assert got == [0, 1, 2, END]
    t0 = time.monotonic()
    with pytest.raises(hevr.RemoteTimeoutError, match="within 1 s"):
        list(server(Script(units(0.6)), timeout=1).frames("/v1/stores/x/stream", {}, 1 << 20))
    assert time.monotonic() - t0 < 10


def test_retry_after_dates():
    from datetime import datetime, timedelta, timezone
    from email.utils import format_datetime

    when = datetime.now(timezone.utc) + timedelta(seconds=30)
    assert 25 <= retry_after(format_datetime(when, usegmt=True)) <= 31
    assert retry_after("Mon, 01 Jan 1990 00:00:00 GMT") == 0.0
    assert retry_after("99999999999") == 86400.0 and retry_after("x" * 100) is None
