"""viser's single-file web client, as shipped in the installed viser wheel (served at /viewer/)."""

from __future__ import annotations

from pathlib import Path


def client_dir() -> Path:
    """The directory holding viser's built client (`index.html`, one file with everything inlined)."""
    import importlib.util

    spec = importlib.util.find_spec("viser")
    if spec is None or spec.origin is None:
        raise RuntimeError("viser is not installed; the 3D view needs it (pip install viser)")
    return Path(spec.origin).parent / "client" / "build"
