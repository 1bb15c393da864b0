"""Which format a calibration file looks like, for the refusal of a file read with the wrong `--from`."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from workers.rigs.formats.caliscope import camera_tables

# Formats whose files are the same layout: reading one as the other is no mistake.
_SAME = {"anipose": "anipose", "pose2sim": "anipose"}


def _toml(path: Path) -> tuple[str, str] | None:
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    tables = camera_tables(data)
    if tables is not None:
        layout = "camera_array.toml" if "cameras" in data else "config.toml"
        return "caliscope", f"a caliscope {layout}"
    if any(isinstance(t, dict) and {"name", "matrix", "rotation"} <= t.keys() for t in data.values()):
        return "anipose", "an Anipose / Pose2Sim calibration.toml"
    return None


def _json(path: Path) -> tuple[str, str] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if isinstance(data, dict) and "camera_poses" in data:
        return "multical", "a multical calibration.json"
    if isinstance(data, dict) and isinstance(data.get("cameras"), list) and any(
            isinstance(c, dict) and "distCoef" in c for c in data["cameras"]):
        return "panoptic", "a CMU Panoptic calibration JSON"
    return None


def _folder(path: Path) -> tuple[str, str] | None:
    if (path / "intri.yml").is_file() and (path / "extri.yml").is_file():
        return "easymocap", "an EasyMocap intri.yml / extri.yml folder"
    if any((path / f"cameras.{ext}").is_file() for ext in ("txt", "bin")):
        return "colmap", "a COLMAP model folder"
    return None


def looks_like(path: Path) -> tuple[str, str] | None:
    """(format, description) of the format `path` looks like, or None when it is none we can tell apart."""
    path = Path(path)
    if path.is_dir():
        return _folder(path)
    if not path.is_file():
        return None
    if path.suffix.lower() == ".toml":
        return _toml(path)
    if path.suffix.lower() == ".json":
        return _json(path)
    return None


def mismatch(fmt: str, path: Path) -> str | None:
    """A sentence naming the format `path` looks like when that is not `fmt`, else None."""
    found = looks_like(path)
    if found is None or _SAME.get(found[0], found[0]) == _SAME.get(fmt, fmt):
        return None
    return f"{path}: this looks like {found[1]}, not {fmt}'s layout: use --from {found[0]}"
