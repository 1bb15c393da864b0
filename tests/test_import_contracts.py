"""The import contracts of pyproject.toml ([tool.importlinter]): kept by the tree, and able to fail.

scripts/test.sh runs `lint-imports` on the tree itself; these tests show that each kind of wrong-way import
the contracts exist for is caught, with the modules named, in a copy of the tree with one bad import added.
"""

from __future__ import annotations

import ast
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
    ("backend/broker/outbox.py", "import backend.services.leases.queues", "Web side: routes -> services",
     "backend.broker.outbox -> backend.services.leases.queues"),
    ("backend/services/leases/queues.py", "import workers.tasks.fits", "never imports the job layer",
     "backend.services.leases.queues -> workers.tasks.fits"),
    ("backend/api/routes/health.py", "import backend.bench.common", "tools on top",
     "backend.api.routes.health -> backend.bench.common"),
    ("backend/services/audit.py", "import backend.services.jobs.jobs", "No import circles",
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


# --- imports inside functions: only where they keep a heavy or optional dependency out of a start-up ----------

DEFERRED = "# deferred:"
CLI_COMMANDS = ROOT / "backend" / "cli" / "commands"
# What the start-ups must not load: torch and the other heavy or optional libraries of the compute side.
HEAVY = ("torch", "cv2", "PIL", "scipy", "matplotlib", "skimage", "trimesh", "viser", "ai_edge_litert")


def _function_level_imports(path: Path):
    """(import node, enclosing function node) for every import statement inside a function body."""
    def visit(node: ast.AST, function: ast.AST | None):
        for child in ast.iter_child_nodes(node):
            if function is not None and isinstance(child, (ast.Import, ast.ImportFrom)):
                yield child, function
            inner = child if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else function
            yield from visit(child, inner)
    yield from visit(ast.parse(path.read_text()), None)


def _sources():
    for part in ("backend", "workers"):
        yield from sorted((ROOT / part).rglob("*.py"))


def _explained(lines: list[str], node: ast.AST, function: ast.AST) -> bool:
    """A `# deferred: reason` on the import's lines or the line before, or earlier in the same function (one
    comment for a function that defers several)."""
    return any(DEFERRED in line for line in lines[function.lineno - 1:node.end_lineno])


def test_every_function_level_import_says_why_it_is_deferred() -> None:
    cli_reason = ast.get_docstring(ast.parse((CLI_COMMANDS / "__init__.py").read_text())) or ""
    assert "deferred:" in cli_reason, "the CLI commands' package docstring gives their reason"
    seen, unexplained = 0, []
    for path in _sources():
        lines = path.read_text().splitlines()
        for node, function in _function_level_imports(path):
            seen += 1
            if CLI_COMMANDS in path.parents or _explained(lines, node, function):
                continue
            unexplained.append(f"{path.relative_to(ROOT)}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    assert seen > 100, "the scan found the tree's deferred imports"
    assert not unexplained, ("an import inside a function needs a `# deferred: reason` (what start-up it keeps "
                             "which dependency out of), else it goes to the top of the module:\n"
                             + "\n".join(unexplained))


def test_no_standard_library_module_is_imported_inside_a_function() -> None:
    """The standard library never needs deferring (nor do the CLI's commands: their reason is the heavy ones)."""
    inside = []
    for path in _sources():
        for node, _ in _function_level_imports(path):
            if isinstance(node, ast.ImportFrom) and node.level:
                continue  # relative: our own modules
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            if any(name.split(".")[0] in sys.stdlib_module_names for name in names):
                inside.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not inside, inside


def _loaded_by(code: str) -> set[str]:
    """The top-level packages a fresh interpreter has loaded after running `code` in the repository root."""
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(ROOT), "HANDLOOP_DATABASE_URL": "sqlite://"}
    script = code + "\nimport sys; print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    return set(result.stdout.split())


def test_the_api_start_up_loads_no_torch_nor_other_heavy_library() -> None:
    loaded = _loaded_by("import backend.app, backend.api.main; from backend.app import create_app; create_app()")
    assert "backend" in loaded and "fastapi" in loaded
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))


def test_the_cli_start_up_loads_no_torch_nor_the_web_and_data_libraries() -> None:
    """`handloop --help` imports every command module (backend.cli.main registers them all)."""
    loaded = _loaded_by("import backend.cli.main")
    assert "typer" in loaded
    assert not loaded & {*HEAVY, "numpy", "sqlalchemy", "pydantic", "fastapi", "celery"}
