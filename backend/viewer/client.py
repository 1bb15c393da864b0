"""viser's single-file web client, as shipped in the installed viser wheel (served at /viewer/)."""

from __future__ import annotations

import base64
import hashlib
import html
import importlib.util
import re
from pathlib import Path

import zstandard


def client_dir() -> Path:
    """The directory holding viser's built client (`index.html`, one file with everything inlined)."""

    spec = importlib.util.find_spec("viser")
    if spec is None or spec.origin is None:
        raise RuntimeError("viser is not installed; the 3D view needs it (pip install viser)")
    return Path(spec.origin).parent / "client" / "build"


# viser's index.html is one inline loader script whose `data-p` attribute holds the client, zstd-compressed and
# written in an 88-character alphabet (decoded by the loader's `de`); the loader inserts the CSS as a <style> and
# the code as an inline <script type="module">. Their hashes let the viewer's Content-Security-Policy allow
# exactly these two scripts instead of any inline script.
_ALPHABET = "!#$%()*+,-./0123456789:;=?@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_abcdefghijklmnopqrstuvwxyz{|}~"


def _decode_88(text: str) -> bytes:
    """The loader's `de`: 5 characters -> 4 bytes (big-endian), a tail of r characters -> r - 1 bytes."""
    index = {c: i for i, c in enumerate(_ALPHABET)}
    whole, tail = divmod(len(text), 5)
    out = bytearray()
    for start in range(0, whole * 5, 5):
        value = 0
        for char in text[start:start + 5]:
            value = value * 88 + index[char]
        out += value.to_bytes(4, "big")
    if tail:
        value = 0
        for char in text[whole * 5:]:
            value = value * 88 + index[char]
        out += value.to_bytes(tail - 1, "big")
    return bytes(out)


def client_script_hashes() -> list[str]:
    """CSP sources (`'sha256-...'`) of the scripts viser's client runs: the inline loader and the module it
    inserts. ValueError if the page does not have the expected shape (a viser release that changed it)."""


    page = (client_dir() / "index.html").read_text(encoding="utf-8")
    found = re.search(r'<script data-p="([^"]*)"([^>]*)>(.*?)</script>', page, re.S)
    sizes = found and re.search(r'data-ss="(\d+)"', found.group(2)), found and re.search(r'data-cs="(\d+)"',
                                                                                             found.group(2))
    if found is None or not all(sizes):
        raise ValueError(f"viser's {client_dir() / 'index.html'} has no loader script of the known shape")
    style_size, code_size = (int(m.group(1)) for m in sizes)  # type: ignore[union-attr]
    payload = zstandard.ZstdDecompressor().decompress(_decode_88(html.unescape(found.group(1))),
                                                      max_output_size=style_size + code_size)
    scripts = [found.group(3).encode("utf-8"), payload[style_size:style_size + code_size]]
    return [f"'sha256-{base64.b64encode(hashlib.sha256(s).digest()).decode()}'" for s in scripts]
