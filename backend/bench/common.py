"""The benchmark convention: progress on stderr, one JSON object as the last line of stdout, recording
how the run was made (commit, machine, settings)."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def git_commit() -> str:
    """The checkout's commit (with '+dirty' when files changed), or 'unknown' outside git."""
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                                text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return commit + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def machine_info() -> dict[str, Any]:
    import torch  # deferred: bench api and bench import load torch only here, once they have measured

    info: dict[str, Any] = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.is_available(),
    }
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
    return info


def emit(name: str, result: dict[str, Any], settings: dict[str, Any], started_s: float) -> dict[str, Any]:
    """Add run metadata to `result` and print it as the last stdout line."""
    record = {
        "benchmark": name,
        **result,
        "settings": settings,
        "commit": git_commit(),
        "machine": machine_info(),
        "wall_s": round(time.perf_counter() - started_s, 3),
        "argv": sys.argv[1:],
    }
    sys.stdout.write(json.dumps(record) + "\n")
    sys.stdout.flush()
    return record
