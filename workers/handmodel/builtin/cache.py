"""On-disk cache of the generated built-in hand (an .npz keyed by the generator version).

Location: $HANDLOOP_DATA_DIR/cache if set, else ~/.cache/handloop. A file that cannot be read, lacks a
field, or was written by another generator version is ignored (and later overwritten); writes go to a
temporary file first and are renamed into place, so concurrent workers never see half a file.
"""

from __future__ import annotations

import logging
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)


def cache_dir() -> Path:
    """Directory of the generated-model cache (not created here)."""
    data_dir = os.environ.get("HANDLOOP_DATA_DIR")
    if data_dir:
        return Path(data_dir) / "cache"
    return Path.home() / ".cache" / "handloop"


def prune(directory: Path, pattern: str, keep: Path) -> None:
    """Delete files matching `pattern` in `directory` other than `keep` (entries of older generators)."""
    for old in directory.glob(pattern):
        if old != keep:
            try:
                old.unlink()
            except OSError as exc:
                logger.debug("could not remove stale cache %s: %s", old, exc)


def load_npz(path: Path, version: str, required: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    """Arrays stored at `path` if it is a complete cache entry for `version`, else None."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["generator_version"]) != version:
                logger.info("stale hand-model cache %s: regenerating", path)
                return None
            out = {key: data[key] for key in data.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        logger.warning("unreadable hand-model cache %s (%s): regenerating", path, exc)
        return None
    missing = [key for key in required if key not in out]
    if missing:
        logger.warning("incomplete hand-model cache %s (missing %s): regenerating", path, missing)
        return None
    return out


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write `arrays` to `path` atomically; failures are logged, never raised (the cache is optional)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.chmod(tmp, 0o644)  # a shared data dir serves several workers
        os.replace(tmp, path)
    except OSError as exc:
        logger.warning("could not write hand-model cache %s: %s", path, exc)
