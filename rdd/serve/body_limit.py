"""A request body size limit for the server, as ASGI middleware: a body over the limit answers 413
``{"error": "body: ..."}`` before it reaches the app (uvicorn has no limit of its own).

A declared ``Content-Length`` over the limit is refused before any of the body is read; a body sent
without one (chunked) is counted as it arrives and refused once it passes the limit.
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from typing import Any

DEFAULT_MAX_BODY_BYTES = 64 << 20  # 64 MiB: a request of paths is kilobytes; this only stops abuse

Message = dict[str, Any]
ASGIApp = Callable[[dict, Callable[[], Awaitable[Message]], Callable[[Message], Awaitable[None]]], Awaitable[None]]


class BodyLimit:
    """Wrap ``app``: request bodies of more than ``max_bytes`` bytes answer 413 with a one-line JSON error."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        if max_bytes < 1:
            raise ValueError(f"must be at least 1 byte, got {max_bytes}")
        self.app, self.max_bytes = app, int(max_bytes)

    async def _refuse(self, send: Callable[[Message], Awaitable[None]]) -> None:
        body = json.dumps({"error": f"body: larger than the server's limit of {self.max_bytes} bytes "
                                    "(--max-body-bytes)"}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: dict, receive: Callable[[], Awaitable[Message]],
                       send: Callable[[Message], Awaitable[None]]) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None and declared.strip().isdigit() and int(declared) > self.max_bytes:
            await self._refuse(send)
            return
        state = {"seen": 0, "refused": False, "started": False}

        async def counted_receive() -> Message:
            message = await receive()
            if message["type"] == "http.request" and not state["refused"]:
                state["seen"] += len(message.get("body", b""))
                if state["seen"] > self.max_bytes and not state["started"]:
                    state["refused"] = True
                    await self._refuse(send)
            # the app sees a client gone away once the body is refused, and stops reading it
            return {"type": "http.disconnect"} if state["refused"] else message

        async def guarded_send(message: Message) -> None:
            if state["refused"]:
                return  # the 413 is the answer: drop whatever the app tries to send after it
            state["started"] = True
            await send(message)

        try:
            await self.app(scope, counted_receive, guarded_send)
        except Exception:
            if not state["refused"]:
                raise
            # the app's error over the disconnect it was shown, after the 413 was sent: nothing to report
