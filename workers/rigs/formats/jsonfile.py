"""Reading a JSON calibration file with errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from workers.rigs.formats.common import FormatError


def load(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FormatError(f"{path}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path}: not valid JSON ({exc})") from None
