"""Fixtures for every test directory: the live stack (tests/support/live_stack.py), and whether the detector's
model files are installed."""


import pytest

from tests.support.live_stack import capture_cache, live_stack  # noqa: F401  (fixtures, registered by import)
from tests.support.requirements import missing


@pytest.fixture
def require_detector() -> None:
    """Skip where the model files are absent, except in CI, where their absence is a failure of the set-up."""
    from workers.detector import detector_status

    status = detector_status()
    if status is None:
        return
    missing(f"the detector's model files are not installed: {status}", needed_by="the detector's tests")
