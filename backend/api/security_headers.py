"""Security headers on every response: a Content-Security-Policy per kind of page, nosniff, and no Referer.

The bearer token sits in the UI's localStorage, so a script injected into any page served from this origin
could read it: each policy allows scripts from this server only. The three kinds of page:

- the UI (/, also every API response): its own ES modules and CSS; images and masks are blobs drawn on canvases;
  it embeds the 3D view (/viewer/) in an iframe; nothing may frame it.
- viser's client (/viewer/): one inline loader script that instantiates WebAssembly (zstd) and inserts the client
  as an inline module and a <style>: those two scripts are allowed by their hashes (backend.viewer.client), plus
  'wasm-unsafe-eval'; its workers (Draco mesh decoding) are blob: URLs; its UI library sets inline styles; the
  recording is fetched from this server; only the UI (same origin) may frame it.
- Swagger UI (/docs): its files from this server (backend.api.docs); inline styles and data: images of its CSS.

Referrer-Policy no-referrer: scene tickets travel in URLs (?ticket=), so no request may carry them elsewhere.
"""

from __future__ import annotations

import logging
from functools import cache
from typing import Any

from backend.viewer.client import client_script_hashes

logger = logging.getLogger(__name__)

COMMON = ("object-src 'none'", "base-uri 'none'", "form-action 'self'")
UI_POLICY = "; ".join(("default-src 'self'", "script-src 'self'", "style-src 'self'", "img-src 'self' data: blob:",
                       "connect-src 'self'", "frame-src 'self'", "worker-src 'self'", "frame-ancestors 'none'",
                       *COMMON))
DOCS_POLICY = "; ".join(("default-src 'self'", "script-src 'self'", "style-src 'self' 'unsafe-inline'",
                         "img-src 'self' data:", "connect-src 'self'", "frame-ancestors 'none'", *COMMON))


@cache  # hashing viser's client takes ~70 ms; it changes only with the installed viser
def viewer_policy() -> str:
    try:
        scripts = " ".join(client_script_hashes())
    except (OSError, ValueError) as exc:  # a viser release that packs its client differently: say so, keep working
        logger.warning("viser's client scripts could not be hashed (%s); /viewer/ allows inline scripts", exc)
        scripts = "'unsafe-inline'"
    return "; ".join(("default-src 'self'", f"script-src 'self' {scripts} 'wasm-unsafe-eval' 'unsafe-eval'",
                      "style-src 'self' 'unsafe-inline'", "img-src 'self' data: blob:", "font-src 'self' data:",
                      "connect-src 'self' data: blob:", "worker-src 'self' blob:", "frame-ancestors 'self'", *COMMON))


class SecurityHeaders:
    """ASGI middleware adding the headers to every HTTP response (errors and static files included)."""

    def __init__(self, app: Any) -> None:
        self.app = app
        base = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer")]
        self._headers = {
            "ui": [*base, (b"content-security-policy", UI_POLICY.encode()), (b"x-frame-options", b"DENY")],
            "docs": [*base, (b"content-security-policy", DOCS_POLICY.encode()), (b"x-frame-options", b"DENY")],
            "viewer": [*base, (b"content-security-policy", viewer_policy().encode()),
                       (b"x-frame-options", b"SAMEORIGIN")],
        }

    @staticmethod
    def kind(path: str) -> str:
        if path == "/viewer" or path.startswith("/viewer/"):
            return "viewer"
        if path == "/docs" or path.startswith("/docs/"):
            return "docs"
        return "ui"

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = self._headers[self.kind(scope.get("path", ""))]

        async def with_headers(event: dict) -> None:
            if event["type"] == "http.response.start":
                names = {name.lower() for name, _ in event.get("headers", [])}
                event["headers"] = [*event.get("headers", []), *(h for h in extra if h[0] not in names)]
            await send(event)

        await self.app(scope, receive, with_headers)
