"""A loaded machine for tests that must not depend on timing: busy processes beside the test.

Each busy process ends by itself after `limit_s` (should the test runner die before stopping it) and is
stopped when the block or the fixture ends, whatever the test's outcome.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

BUSY_LOOP = "import time\nend = time.monotonic() + {limit_s}\nwhile time.monotonic() < end:\n    pass\n"


@contextmanager
def busy_cpu(processes: int = 1, limit_s: float = 900.0) -> Iterator[list[subprocess.Popen]]:
    """`processes` processes spinning on a CPU each, for at most `limit_s` seconds."""
    busy: list[subprocess.Popen] = []
    try:
        for _ in range(processes):
            busy.append(subprocess.Popen([sys.executable, "-c", BUSY_LOOP.format(limit_s=float(limit_s))]))
        yield busy
    finally:
        for process in busy:
            if process.poll() is None:
                process.kill()
            process.wait(timeout=30)


@pytest.fixture
def cpu_loaded() -> Iterator[list[subprocess.Popen]]:
    """One busy process per `HANDLOOP_TEST_BUSY_PROCESSES` (default 1) beside the test, always stopped."""
    with busy_cpu(int(os.environ.get("HANDLOOP_TEST_BUSY_PROCESSES", "1"))) as busy:
        yield busy
        assert all(process.poll() is None for process in busy), "a busy process ended before the test did"
