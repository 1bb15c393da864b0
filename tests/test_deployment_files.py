"""docker-compose.yml parses and names commands, modules and settings that exist; the Dockerfile copies what
the package needs (no Docker engine here: the files are checked, not run)."""

from __future__ import annotations

import importlib.util
import re
import shlex
from pathlib import Path

import yaml
from typer.testing import CliRunner

from backend.broker.celery_queue import QUEUES
from backend.cli.main import app
from backend.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
SERVICES = {"postgres", "redis", "api", "worker-cpu", "worker-gpu"}


def _compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def _handloop_commands(compose: dict) -> dict[str, list[str]]:
    return {name: s["command"] for name, s in compose["services"].items()
            if isinstance(s.get("command"), list) and s["command"][:1] == ["handloop"]}


def test_compose_file_parses_and_names_real_commands():
    compose = _compose()
    assert set(compose["services"]) >= SERVICES
    runner = CliRunner()
    commands = _handloop_commands(compose)
    assert set(commands) == {"api", "worker-cpu", "worker-gpu"}
    for command in commands.values():
        result = runner.invoke(app, [*command[1:2], "--help"])
        assert result.exit_code == 0, (command, result.output)
        for option in (part for part in command[2:] if part.startswith("--")):
            assert option in result.output, (command, option)


def test_workers_consume_the_queues_and_the_gpu_worker_reserves_a_gpu():
    services = _compose()["services"]
    queues = {}
    for name in ("worker-cpu", "worker-gpu"):
        command = services[name]["command"]
        queues[name] = command[command.index("--queues") + 1].split(",")
        assert set(queues[name]) <= set(QUEUES)
    assert queues == {"worker-cpu": ["cpu"], "worker-gpu": ["gpu"]}
    devices = services["worker-gpu"]["deploy"]["resources"]["reservations"]["devices"]
    assert any(d.get("driver") == "nvidia" and "gpu" in d.get("capabilities", []) for d in devices)


def test_every_service_is_health_checked_and_uses_declared_volumes():
    compose = _compose()
    declared = set(compose["volumes"])
    for name, service in compose["services"].items():
        assert "healthcheck" in service, name
        for volume in service.get("volumes", []):
            assert volume.split(":")[0] in declared, (name, volume)
    # API and workers share the data folder (images, masks, checkpoints): the distributed storage.
    data = {name: [v for v in compose["services"][name].get("volumes", []) if v.endswith(":/data")]
            for name in ("api", "worker-cpu", "worker-gpu")}
    assert all(data.values()) and len({v[0] for v in data.values()}) == 1


def test_health_checks_and_environment_name_real_modules_and_settings():
    compose = _compose()
    fields = {f"HANDLOOP_{name.upper()}" for name in Settings.model_fields}
    for name, service in compose["services"].items():
        test = service["healthcheck"]["test"]
        text = test[1] if test[0] == "CMD-SHELL" else " ".join(test[1:])
        for module in re.findall(r"-A\s+(\S+)", text):
            assert importlib.util.find_spec(module) is not None, (name, module)
        if "celery" in text:
            node = shlex.split(text.replace("$$", "$"))[-1].split("@")[0]
            assert f"{node}@%h" in service["command"], (name, node)  # pings the node this service runs
        for key in (service.get("environment") or {}):
            if key.startswith("HANDLOOP_"):
                assert key in fields, (name, key)
    env = compose["services"]["worker-gpu"]["environment"]
    assert env["HANDLOOP_BROKER_URL"].startswith("redis://redis:")
    settings = Settings(broker_visibility_timeout_s=int(env["HANDLOOP_BROKER_VISIBILITY_TIMEOUT_S"]),
                        task_time_limit_s=int(env["HANDLOOP_TASK_TIME_LIMIT_S"]),
                        nets_config=env["HANDLOOP_NETS_CONFIG"])  # validates the visibility timeout
    assert settings.broker_visibility_timeout_s > settings.task_time_limit_s


def test_dockerfile_copies_what_the_package_needs():
    text = (ROOT / "Dockerfile").read_text()
    for needed in ("backend", "workers", "frontend", "migrations", "alembic.ini", "pyproject.toml"):
        assert f"COPY {needed}" in text or f" {needed} " in text, needed
    # alembic.ini, migrations/ and frontend/ are found beside the packages: the install must be editable.
    assert re.search(r"pip install [^\n]*-e \.", text)
