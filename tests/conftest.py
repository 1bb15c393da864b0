"""Fixtures for every test directory: the live stack (tests/support/live_stack.py)."""

from tests.support.live_stack import capture_cache, live_stack  # noqa: F401  (fixtures, registered by import)
