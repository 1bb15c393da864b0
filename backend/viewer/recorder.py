"""One `viser.ViserServer` per process, used only to serialise scenes into `.viser` recordings.

viser writes recordings through a server's scene API (`get_scene_serializer`), so the process keeps one,
bound to an ephemeral loopback port that no page uses (browsers play the recordings through the
backend's own routes). Scenes are built one at a time under a lock and the scene is emptied again right
after, so the server holds nothing between recordings.
"""

from __future__ import annotations

import contextlib
import io
import logging
import threading
from collections.abc import Callable
from typing import Any

logger = logging.getLogger(__name__)

_lock = threading.Lock()
_server: Any = None


def _get_server() -> Any:
    global _server
    if _server is None:
        import viser  # deferred: viser (~0.5 s) with the first recording; the API imports this module

        banner = io.StringIO()
        with contextlib.redirect_stdout(banner):  # viser prints its URLs; they are of no use to anyone here
            _server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        logger.info("viser scene recorder on 127.0.0.1:%s (internal, serialises recordings only)",
                    _server.get_port())
    return _server


def record(build: Callable[[Any], None]) -> bytes:
    """Run `build(scene)` on an empty scene and return the scene as `.viser` bytes."""
    with _lock:
        server = _get_server()
        server.scene.reset()
        try:
            build(server.scene)
            return server.get_scene_serializer().serialize()
        finally:
            server.scene.reset()


def viser_version() -> str:
    import viser  # deferred: as in _get_server

    return viser.__version__
