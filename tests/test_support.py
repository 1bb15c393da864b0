"""The test support's own rules: a missing requirement skips, except in CI, where it fails."""

from __future__ import annotations

import pytest

from tests.support.requirements import missing


def test_a_missing_requirement_skips_outside_ci(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="no server here"):
        missing("no server here", needed_by="the server tests")


def test_a_missing_requirement_fails_in_ci_naming_what_must_run(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match=r"no server here \(CI is set: the server tests must run\)"):
        missing("no server here", needed_by="the server tests")
