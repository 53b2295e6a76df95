"""What the station accepts before any route sees a request: small bodies, no uploads.

The station's forms are a few fields each (log-in, acknowledge, user changes); nothing is
uploaded. So a request body is read here, in memory, up to :data:`MAX_BODY` bytes, and
answered 413 beyond that before a route or a form parser runs; a multipart body (which the
form parser would spool to disk, unauthenticated on ``/login``) is answered 415 unread.
How uvicorn is told which proxies may set ``X-Forwarded-For`` is here too.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, MutableMapping, Sequence
from typing import Any

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

MAX_BODY = 64 * 1024
"""Bytes of the largest request body heard (a form of a few fields is well under 4 KiB)."""


async def _answer(send: Send, status: int, text: str) -> None:
    body = (text + "\n").encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


class RequestLimits:
    """ASGI middleware: a body of at most ``max_body`` bytes and never multipart."""

    def __init__(self, app: ASGIApp, max_body: int = MAX_BODY) -> None:
        self.app = app
        self.max_body = max_body

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.lower(): v for k, v in scope.get("headers", [])}
        if headers.get(b"content-type", b"").lower().lstrip().startswith(b"multipart/"):
            await _answer(send, 415, "multipart bodies are not accepted; send a plain form")
            return
        declared = headers.get(b"content-length")
        if declared is not None:
            if not declared.strip().isdigit():
                await _answer(send, 400, "bad Content-Length")
                return
            if int(declared) > self.max_body:
                await _answer(send, 413, f"request body larger than {self.max_body} bytes")
                return
        body = bytearray()
        while True:  # chunked bodies have no length: count while reading
            message = await receive()
            if message["type"] != "http.request":
                await self.app(scope, _replay(message, receive), send)
                return
            body += message.get("body", b"")
            if len(body) > self.max_body:
                await _answer(send, 413, f"request body larger than {self.max_body} bytes")
                return
            if not message.get("more_body", False):
                break
        await self.app(scope, _replay({"type": "http.request", "body": bytes(body),
                                       "more_body": False}, receive), send)


def _replay(first: Message, receive: Receive) -> Receive:
    """``receive`` that hands out ``first`` once, then the real messages (disconnects)."""
    pending = [first]

    async def replayed() -> Message:
        return pending.pop() if pending else await receive()

    return replayed


def uvicorn_options(trusted_proxies: Sequence[str] = ()) -> dict[str, Any]:
    """uvicorn settings for the station: ``X-Forwarded-For``/``-Proto`` are believed only
    from ``trusted_proxies`` (addresses or networks). By default none: uvicorn would
    otherwise believe them from 127.0.0.1, so anyone on the station's own machine (or a
    local reverse proxy passing headers through) could choose the address that the audit
    table and the log-in throttle see."""
    if not trusted_proxies:
        return {"proxy_headers": False, "forwarded_allow_ips": ""}
    return {"proxy_headers": True, "forwarded_allow_ips": ",".join(trusted_proxies)}
