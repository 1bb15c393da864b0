"""`handloop docs figures`: the docs' figures about the code, printed from the code (backend/cli/doc_figures.py)."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    docs = typer.Typer(help="The docs' figures about the code, printed from the code and checked.",
                       no_args_is_help=True)
    app.add_typer(docs, name="docs")

    @docs.command("figures")
    def figures(
        names: list[str] | None = typer.Argument(None, help="Figures to print (default: all)."),
        check: bool = typer.Option(False, "--check", help="Exit 1 naming each page that disagrees with the code "
                                   "(a figure's block; a route missing from docs/api.md; a benchmark missing "
                                   "from docs/benchmarks.md)."),
        write: bool = typer.Option(False, "--write", help="Rewrite the pages' generated blocks from the code."),
    ) -> None:
        """Print each figure as its page's generated block holds it (<!-- figures:NAME ... --> markers)."""
        from backend.cli import doc_figures  # deferred: grimp and the application, only for this command

        if check and write:
            raise typer.BadParameter("--check and --write do not go together: --write, then --check")
        unknown = [n for n in names or [] if n not in doc_figures.FIGURES]
        if unknown:
            raise typer.BadParameter(f"no figure named {', '.join(unknown)}; the figures are: "
                                     f"{', '.join(doc_figures.FIGURES)}")
        if write:
            changed = doc_figures.write_pages()
            typer.echo("rewrote " + ", ".join(changed) if changed else "the pages already hold today's figures")
            return
        if check:
            problems = (doc_figures.page_disagreements() + doc_figures.route_disagreements()
                        + doc_figures.benchmark_page_disagreements())
            for problem in problems:
                typer.echo(problem, err=True)
            if problems:
                typer.echo("run `handloop docs figures --write` (routes and benchmarks go on their pages by hand)",
                           err=True)
                raise typer.Exit(1)
            typer.echo("the docs agree with the code")
            return
        for name in names or list(doc_figures.FIGURES):
            page = doc_figures.FIGURES[name][0]
            typer.echo(f"## {name} (docs/{page})\n{doc_figures.render(name)}")
