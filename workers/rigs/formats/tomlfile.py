"""Reading a TOML calibration file with errors that name the file."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from workers.rigs.formats.common import FormatError


def load(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FormatError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise FormatError(f"{path}: a folder; this format is one .toml file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path}: not valid TOML ({exc})") from None
