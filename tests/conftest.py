"""Fixtures for every test directory: the live stack (tests/support/live_stack.py), and whether the detector's
model files are installed."""

import os

import pytest

from tests.support.live_stack import capture_cache, live_stack  # noqa: F401  (fixtures, registered by import)


@pytest.fixture
def require_detector() -> None:
    """Skip where the model files are absent, except in CI, where their absence is a failure of the set-up."""
    from workers.detector import detector_status

    status = detector_status()
    if status is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI must install the detector's model files: {status}")
    pytest.skip(f"detector not installed: {status}")
