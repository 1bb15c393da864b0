"""Entry point of the `handloop` CLI.

Every module in `backend.cli.commands` defines `register(app, bench)` and adds its commands; modules
import heavy dependencies (torch, the workers) inside the commands, so `handloop --help` stays fast.
"""

from __future__ import annotations

import importlib
import logging
import pkgutil

import typer

from backend.cli import commands

app = typer.Typer(
    name="handloop",
    help="Human-in-the-loop 3D hand pose and shape labeling (FreiHAND's procedure).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
bench = typer.Typer(help="Benchmarks: each prints one JSON object as its last stdout line.", no_args_is_help=True)
app.add_typer(bench, name="bench")


@app.callback()
def main(verbose: bool = typer.Option(False, "--verbose", "-v", help="Log debug messages.")) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")


for module_info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
    importlib.import_module(f"{commands.__name__}.{module_info.name}").register(app, bench)

if __name__ == "__main__":  # `python -m backend.cli.main ...`, as the `handloop` entry point
    app(prog_name="handloop")
