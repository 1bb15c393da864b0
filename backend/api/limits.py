"""Refuse oversized request bodies before they are read whole (declared or streamed)."""

from __future__ import annotations

from typing import Any

from fastapi.responses import JSONResponse


class BodySizeLimit:
    """ASGI middleware: 413 when Content-Length exceeds the limit, or as soon as a streamed body grows
    past it (the app then sees a disconnect and its response is dropped)."""

    def __init__(self, app: Any, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        message = f"request body exceeds the limit of {self.max_bytes} bytes"
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = 0
                if declared > self.max_bytes:
                    await JSONResponse({"detail": message}, status_code=413)(scope, receive, send)
                    return
        received = 0
        answered = False

        async def guarded_send(event: dict) -> None:
            if not answered:  # once we have answered 413, the app's own response is dropped
                await send(event)

        async def limited_receive() -> dict:
            nonlocal received, answered
            if answered:
                return {"type": "http.disconnect"}
            event = await receive()
            if event["type"] == "http.request":
                received += len(event.get("body", b""))
                if received > self.max_bytes:
                    await JSONResponse({"detail": message}, status_code=413)(scope, receive, send)
                    answered = True
                    return {"type": "http.disconnect"}  # the app stops reading and writes nothing
            return event

        await self.app(scope, limited_receive, guarded_send)
