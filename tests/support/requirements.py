"""What a test needs from the machine (a server, a browser, model files): skipped where it is missing, except in
CI (the CI environment variable set), where a missing requirement is a failure of the set-up, not a skip."""

from __future__ import annotations

import os
from typing import NoReturn

import pytest


def in_ci() -> bool:
    """Whether the CI environment variable is set (to anything but the empty string)."""
    return bool(os.environ.get("CI"))


def missing(message: str, *, needed_by: str) -> NoReturn:
    """Skip the test for `message`, or fail it in CI, saying which tests `needed_by` names must run there."""
    if in_ci():
        pytest.fail(f"{message} (CI is set: {needed_by} must run)")
    pytest.skip(message)
