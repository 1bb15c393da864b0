"""docker-compose.yml parses, and every handloop command it runs exists (no Docker engine here)."""

from __future__ import annotations

from pathlib import Path

import yaml
from typer.testing import CliRunner

from backend.cli.main import app

ROOT = Path(__file__).resolve().parents[1]


def test_compose_file_parses_and_names_real_commands():
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    assert {"postgres", "redis", "api"} <= set(compose["services"])
    runner = CliRunner()
    commands = [s["command"] for s in compose["services"].values() if s.get("command", [""])[0] == "handloop"]
    assert commands
    for command in commands:
        result = runner.invoke(app, [*command[1:2], "--help"])
        assert result.exit_code == 0, (command, result.output)
        for option in (part for part in command[2:] if part.startswith("--")):
            assert option in result.output, (command, option)


def test_dockerfile_copies_what_the_package_needs():
    text = (ROOT / "Dockerfile").read_text()
    for needed in ("backend", "workers", "migrations", "alembic.ini", "pyproject.toml"):
        assert f"COPY {needed}" in text or f" {needed} " in text, needed
