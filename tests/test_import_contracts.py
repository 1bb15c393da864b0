"""The import contracts of pyproject.toml ([tool.importlinter]): kept by the tree, and able to fail.

scripts/test.sh runs `lint-imports` on the tree itself; these tests show that each kind of wrong-way import
the contracts exist for is caught, with the modules named, in a copy of the tree with one bad import added.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=tree, env=env, capture_output=True, text=True,
                          timeout=300)


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tree = tmp_path_factory.mktemp("tree")
    for part in ("backend", "workers"):
        shutil.copytree(ROOT / part, tree / part, ignore=shutil.ignore_patterns("__pycache__", "*.npz", "*.pt"))
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    return tree


def test_the_tree_keeps_its_contracts(tree_copy: Path) -> None:
    result = _lint(tree_copy)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(("importer", "line", "contract", "named"), [
    ("workers/geometry/camera.py", "import backend.settings", "The compute core knows no database",
     "workers.geometry.camera -> backend.settings"),
    ("workers/fitting/engine.py", "import sqlalchemy", "The compute core knows no database",
     "workers.fitting.engine -> sqlalchemy"),
    ("backend/models/jobs.py", "import backend.services.audit", "Web side: routes -> services",
     "backend.models.jobs -> backend.services.audit"),
    ("backend/broker/outbox.py", "import backend.services.queues", "Web side: routes -> services",
     "backend.broker.outbox -> backend.services.queues"),
    ("backend/services/queues.py", "import workers.tasks.fits", "never imports the job layer",
     "backend.services.queues -> workers.tasks.fits"),
    ("backend/api/routes/health.py", "import backend.bench.common", "tools on top",
     "backend.api.routes.health -> backend.bench.common"),
    ("backend/services/audit.py", "import backend.services.jobs", "No import circles",
     "backend.services"),
])
def test_a_wrong_way_import_fails_with_the_modules_named(tree_copy: Path, importer: str, line: str, contract: str,
                                                         named: str) -> None:
    path = tree_copy / importer
    original = path.read_text()
    path.write_text(original + f"\n{line}  # added by the test\n")
    try:
        result = _lint(tree_copy)
    finally:
        path.write_text(original)
    assert result.returncode != 0
    assert contract in result.stdout and "BROKEN" in result.stdout, result.stdout
    assert named in result.stdout, result.stdout


def test_every_package_of_workers_but_the_job_layer_is_in_the_core_contract() -> None:
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    core = next(c for c in contracts if c["id"] == "core")
    packages = {f"workers.{p.name}" for p in (ROOT / "workers").iterdir() if (p / "__init__.py").is_file()}
    assert packages - {"workers.tasks"} == set(core["source_modules"]), "a new package of workers/ takes a side"
