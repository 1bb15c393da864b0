"""The figures the docs state about the code, printed from the code (`handloop docs figures`).

A page holds each generated figure between two markers,

    <!-- figures:NAME (generated: handloop docs figures --write) -->
    ...
    <!-- /figures:NAME -->

and tests/test_docs.py fails when the text between them is not what `render(NAME)` prints now: a change that
moves a figure (an import, a module, a benchmark) is not done until `handloop docs figures --write` has rewritten
the page. docs/api.md is checked the other way round: every route of the OpenAPI document is in its role table,
and the table names no route the application does not serve (`route_disagreements`).

Everything here is derived from the tree as it is (packages found by walking backend/ and workers/, benchmarks
from the `handloop bench` command group), so modules may move without this file changing.
"""

from __future__ import annotations

import ast
import re
import tempfile
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
COMMANDS = Path(__file__).resolve().parent / "commands"  # the CLI's command modules
SOURCE_PACKAGES = ("backend", "workers")
JOB_LAYER = "workers.tasks"
JOBS = ("workers.tasks.inference", "workers.tasks.training")
MARKER = re.compile(r"<!-- figures:(?P<name>[\w-]+) \(generated: handloop docs figures --write\) -->\n"
                    r"(?P<body>.*?)<!-- /figures:(?P=name) -->", re.DOTALL)


def _side(module: str) -> str:
    """Which part of the tree a module is in: the job layer, the compute core (the rest of workers/), or backend."""
    if module == JOB_LAYER or module.startswith(JOB_LAYER + "."):
        return "job"
    return "core" if module.startswith("workers.") else "backend"


@dataclass(frozen=True)
class JobCrossings:
    """Import edges between the parts among the modules a job's task module imports (its import closure)."""

    job: str
    modules: int
    job_to_backend: int
    job_to_core: int
    core_up: int  # core -> backend or job layer: the core contract keeps it 0
    backend_to_job: int  # the jobs contract keeps it 0


def job_crossings() -> list[JobCrossings]:
    """Each job's closure and its crossings, as import-linter's graph (grimp) reads them."""
    import grimp  # deferred: a development tool (import-linter's graph), needed only to print these figures

    graph = grimp.build_graph(*SOURCE_PACKAGES, cache_dir=None)  # no cache folder left in the tree
    rows = []
    for job in JOBS:
        mods = {job} | graph.find_upstream_modules(job)
        edges = Counter((_side(a), _side(b)) for a in mods
                        for b in graph.find_modules_directly_imported_by(a) & mods if _side(a) != _side(b))
        rows.append(JobCrossings(job, len(mods), edges["job", "backend"], edges["job", "core"],
                                 edges["core", "backend"] + edges["core", "job"], edges["backend", "job"]))
    return rows


def render_job_boundary() -> str:
    lines = ["| job (module) | modules | job layer -> backend | job layer -> core | core -> backend or job layer "
             "| backend -> job layer |", "|---|---|---|---|---|---|"]
    for row in job_crossings():
        lines.append(f"| {row.job} | {row.modules} | {row.job_to_backend} | {row.job_to_core} | {row.core_up} "
                     f"| {row.backend_to_job} |")
    return "\n".join(lines) + "\n"


def function_level_imports(path: Path) -> int:
    """Import statements inside function bodies of one source file (by AST, as tests/test_import_contracts.py)."""
    def visit(node: ast.AST, in_function: bool) -> int:
        count = 0
        for child in ast.iter_child_nodes(node):
            if in_function and isinstance(child, (ast.Import, ast.ImportFrom)):
                count += 1
            count += visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)))
        return count
    return visit(ast.parse(path.read_text()), False)


def deferred_import_counts() -> dict[str, int]:
    """Imports inside functions: in all, in the CLI (backend/cli), in the job layer, and in the rest."""
    counts: Counter[str] = Counter()
    for package in SOURCE_PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            n = function_level_imports(path)
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            part = "cli" if module.startswith("backend.cli.") else "job" if _side(module) == "job" else "other"
            counts[part] += n
            counts["all"] += n
    return dict(counts)


def render_deferred_imports() -> str:
    c = deferred_import_counts()
    return (f"Imports inside function bodies (by AST) now: **{c['all']}**: backend/cli {c['cli']}; the job layer "
            f"(workers/tasks) {c['job']}; the rest {c['other']}.\n")


@dataclass(frozen=True)
class BenchPlacement:
    """Where a `handloop bench NAME` lives: its CLI wrapper and the backend.bench modules it calls."""

    name: str
    wrapper: str  # path from the repository root
    wrapper_lines: int
    bench_modules: tuple[tuple[str, int], ...]  # (path, lines), backend.bench.common (the JSON printer) left out


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines())


def _module_path(module: str) -> Path | None:
    base = ROOT.joinpath(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.exists():
            return candidate
    return None


def _bench_commands(tree: ast.Module) -> list[str]:
    """The names of the `@bench.command(...)` functions a command module defines (as typer names them)."""
    names = []
    for node in ast.walk(tree):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for decorator in node.decorator_list:
            call = decorator if isinstance(decorator, ast.Call) else None
            func = call.func if call else decorator
            if isinstance(func, ast.Attribute) and func.attr == "command" and isinstance(func.value, ast.Name) \
                    and func.value.id == "bench":
                given = call.args[0] if call and call.args and isinstance(call.args[0], ast.Constant) else None
                names.append(str(given.value) if given else node.name.replace("_", "-"))
    return names


def bench_placement() -> list[BenchPlacement]:
    """Every command of the `handloop bench` group, read from the CLI's command modules' source (by AST: nothing
    imported, so no import circle through the CLI; tests/test_docs.py holds it equal to the built CLI's group)."""
    rows = []
    for wrapper in sorted(COMMANDS.glob("*.py")):
        tree = ast.parse(wrapper.read_text())
        names = _bench_commands(tree)
        if not names:
            continue
        modules = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("backend.bench"):
                candidates = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
                modules.update(m for m in candidates if _module_path(m) is not None)
        modules = {m for m in modules if not any(o.startswith(m + ".") for o in modules)}  # a package's submodule
        paths = sorted(p for m in modules if m != "backend.bench.common" and (p := _module_path(m)) is not None)
        for name in names:
            rows.append(BenchPlacement(name, str(wrapper.relative_to(ROOT)), _lines(wrapper),
                                       tuple((str(p.relative_to(ROOT)), _lines(p)) for p in paths)))
    return sorted(rows, key=lambda r: r.name)


def render_bench_placement() -> str:
    """Which module holds each benchmark (line counts only where a wrapper holds one: they change with any edit)."""
    lines = ["| command | CLI wrapper | benchmark in backend/bench |", "|---|---|---|"]
    for row in bench_placement():
        code = (", ".join(p for p, _ in row.bench_modules)
                or f"none: the wrapper holds the benchmark ({row.wrapper_lines} lines)")
        lines.append(f"| `handloop bench {row.name}` | {row.wrapper} | {code} |")
    return "\n".join(lines) + "\n"


# name -> (the page holding it, what prints it)
FIGURES: dict[str, tuple[str, Callable[[], str]]] = {
    "job-boundary": ("architecture.md", render_job_boundary),
    "deferred-imports": ("architecture.md", render_deferred_imports),
    "bench-placement": ("architecture.md", render_bench_placement),
}


def render(name: str) -> str:
    """The text the page should hold between the markers of figure NAME."""
    if name not in FIGURES:
        raise ValueError(f"no figure named {name!r}; the figures are: {', '.join(FIGURES)}")
    return FIGURES[name][1]()


def blocks_in(text: str) -> dict[str, str]:
    """The generated blocks a page holds, by name."""
    return {m["name"]: m["body"] for m in MARKER.finditer(text)}


def page_disagreements() -> list[str]:
    """A line per figure that is missing from its page or differs from what the code prints now."""
    problems = []
    for name, (page, _) in FIGURES.items():
        held = blocks_in((DOCS / page).read_text()).get(name)
        if held is None:
            problems.append(f"docs/{page} has no block for figure {name!r} (markers <!-- figures:{name} ... -->)")
        elif held != (now := render(name)):
            problems.append(f"docs/{page}, figure {name!r}: the page says\n{held}the code prints\n{now}")
    return problems


def _rewritten(m: re.Match[str]) -> str:
    """A marked block with today's figure between its markers (one this module does not know, as it was)."""
    if m["name"] not in FIGURES:
        return m.group(0)
    return m.string[m.start():m.start("body")] + render(m["name"]) + m.string[m.end("body"):m.end()]


def write_pages() -> list[str]:
    """Rewrite every block that differs; the pages changed (a page without a figure's markers is left alone)."""
    changed = []
    for page in sorted({page for page, _ in FIGURES.values()}):
        path = DOCS / page
        text = path.read_text()
        new = MARKER.sub(_rewritten, text)
        if new != text:
            path.write_text(new)
            changed.append(f"docs/{page}")
    return changed


# --- docs/benchmarks.md against the `handloop bench` commands ------------------------------------------------

FIGURES_TABLE_HEADER = "| benchmark | figure | today | target | command | machine | date (commit) |"


def benchmark_page_disagreements(text: str | None = None) -> list[str]:
    """A line per `handloop bench` command without a row in benchmarks.md's table of today's figures or without
    a section of its own, and per row that does not give all seven columns."""
    text = (DOCS / "benchmarks.md").read_text() if text is None else text
    if FIGURES_TABLE_HEADER not in text:
        return [f"docs/benchmarks.md has no table of today's figures (header {FIGURES_TABLE_HEADER!r})"]
    rows = []
    for line in text[text.index(FIGURES_TABLE_HEADER):].splitlines()[2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
    problems = [f"docs/benchmarks.md's row {' | '.join(r)!r} has {len(r)} columns, not 7" for r in rows if len(r) != 7
                or not all(r)]
    sections = set(re.findall(r"^## (\S+)$", text, re.MULTILINE))
    for row in bench_placement():
        if not any(r[0] == row.name for r in rows):
            problems.append(f"docs/benchmarks.md's table has no row for `handloop bench {row.name}`")
        if row.name not in sections:
            problems.append(f"docs/benchmarks.md has no section '## {row.name}' (how to run it, what it measures)")
    return problems


# --- docs/api.md against the OpenAPI document ---------------------------------------------------------------

ROUTE_TABLE_HEADER = "| Route | Minimum role |"
ROUTE = re.compile(r"`((?:GET|POST|PUT|PATCH|DELETE)(?:/(?:GET|POST|PUT|PATCH|DELETE))*) (/[^` ]*)`")


def _normal(path: str) -> str:
    """A path with its parameters' names dropped (the page says {id} where the code says {sample_id})."""
    return re.sub(r"\{[^}]*\}", "{}", path)


def documented_routes(text: str) -> set[tuple[str, str]]:
    """(METHOD, path) of every route api.md's role table names; `GET/POST /a` and `/a/b|c` name several."""
    start = text.index(ROUTE_TABLE_HEADER)
    table = []
    for line in text[start:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        table.append(line.rsplit("|", 2)[0])  # the route column, not the role
    routes = set()
    for method_part, path in ROUTE.findall("\n".join(table)):
        head, _, last = path.rpartition("/")
        for method in method_part.split("/"):
            for tail in last.split("|"):
                routes.add((method, _normal(f"{head}/{tail}")))
    return routes


def served_routes() -> set[tuple[str, str]]:
    """(METHOD, path) of every operation in the application's OpenAPI document."""
    from backend.app import create_app  # deferred: the web application, built only to read its OpenAPI document
    from backend.settings import Settings  # deferred: as above

    with tempfile.TemporaryDirectory(prefix="handloop-openapi-") as data_dir:
        document = create_app(Settings(data_dir=Path(data_dir))).openapi()
    return {(method.upper(), _normal(path)) for path, operations in document["paths"].items() for method in operations}


def route_disagreements() -> list[str]:
    """A line per route the OpenAPI document has and docs/api.md's role table lacks, and the other way round."""
    documented = documented_routes((DOCS / "api.md").read_text())
    served = served_routes()
    return ([f"docs/api.md's role table lacks {m} {p} (it is in the OpenAPI document)"
             for m, p in sorted(served - documented)]
            + [f"docs/api.md's role table names {m} {p}, which the application does not serve"
               for m, p in sorted(documented - served)])
