"""The docs' figures about the code agree with the code (backend/cli/doc_figures.py, `handloop docs figures`)."""

from __future__ import annotations

import pytest

from backend.cli import doc_figures


@pytest.mark.parametrize("name", list(doc_figures.FIGURES))
def test_each_figure_on_its_page_is_what_the_code_prints(name: str) -> None:
    page, _ = doc_figures.FIGURES[name]
    held = doc_figures.blocks_in((doc_figures.DOCS / page).read_text()).get(name)
    assert held is not None, f"docs/{page} lost the markers of figure {name!r}"
    assert held == doc_figures.render(name), (
        f"docs/{page}'s figure {name!r} disagrees with the code: run `handloop docs figures --write`")


def test_the_job_boundary_keeps_the_contracts_zeros() -> None:
    rows = doc_figures.job_crossings()
    assert {r.job for r in rows} == set(doc_figures.JOBS)
    assert all(r.modules > 10 and r.job_to_backend > 0 and r.job_to_core > 0 for r in rows), rows
    assert all(r.core_up == 0 and r.backend_to_job == 0 for r in rows), rows


def test_the_benchmarks_read_from_source_are_the_cli_bench_group() -> None:
    from backend.cli.main import bench

    registered = {info.name or info.callback.__name__.replace("_", "-") for info in bench.registered_commands}
    assert {r.name for r in doc_figures.bench_placement()} == registered
    assert {"api", "sim", "ui", "fit", "nets"} <= registered, registered


def test_api_md_names_every_route_of_the_openapi_document_and_no_other() -> None:
    problems = doc_figures.route_disagreements()
    assert not problems, "\n".join(problems)


def test_the_route_check_would_see_a_missing_and_an_invented_route() -> None:
    text = (doc_figures.DOCS / "api.md").read_text()
    documented = doc_figures.documented_routes(text)
    assert ("GET", "/api/health") in documented and ("DELETE", "/api/review/samples/{}/draft") in documented
    assert ("POST", "/api/annotate/samples/{}/lease/retake") in documented  # `renew|release|retake`
    trimmed = doc_figures.documented_routes(text.replace("`GET /api/health`, ", "").replace(
        "| none |", "`GET /api/nowhere` | none |", 1))
    assert ("GET", "/api/health") not in trimmed and ("GET", "/api/nowhere") in trimmed


def test_a_block_that_drifted_is_reported_and_rewritten(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    page = tmp_path / "architecture.md"
    page.write_text((doc_figures.DOCS / "architecture.md").read_text().replace(
        doc_figures.render("deferred-imports"), "Imports inside function bodies (by AST) now: **184**.\n"))
    monkeypatch.setattr(doc_figures, "DOCS", tmp_path)
    monkeypatch.setattr(doc_figures, "FIGURES", {"deferred-imports": doc_figures.FIGURES["deferred-imports"]})
    assert [p.split(",")[0] for p in doc_figures.page_disagreements()] == ["docs/architecture.md"]
    assert doc_figures.write_pages() == ["docs/architecture.md"]
    assert doc_figures.page_disagreements() == []
    assert doc_figures.write_pages() == []


def test_benchmarks_md_has_a_row_and_a_section_for_every_benchmark_command() -> None:
    problems = doc_figures.benchmark_page_disagreements()
    assert not problems, "\n".join(problems)


def test_the_benchmark_check_would_see_a_missing_row_and_section() -> None:
    text = (doc_figures.DOCS / "benchmarks.md").read_text()
    lines = [line for line in text.splitlines() if not line.startswith("| jobs |") and line != "## jobs"]
    problems = doc_figures.benchmark_page_disagreements("\n".join(lines))
    assert problems == ["docs/benchmarks.md's table has no row for `handloop bench jobs`",
                        "docs/benchmarks.md has no section '## jobs' (how to run it, what it measures)"]
