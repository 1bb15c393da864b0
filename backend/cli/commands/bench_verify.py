"""`handloop bench verify`: a capture's import, and what full verification of its files costs."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("verify")
    def bench_verify(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="A smaller capture (2 x 6 frames instead of 4 x 12)."),
        capture: Path | None = typer.Option(None, exists=True, file_okay=False,
                                            help="Import this capture (default: synthesise the demo's)."),
        repeats: int = typer.Option(3, min=1, max=50, help="Imports, each into a fresh database; medians."),
        width: int | None = typer.Option(None, min=32, max=4096, help="Image width (default: settings)."),
    ) -> None:
        """Time an import's phases (read, full verification, write) into temporary databases."""
        from backend.bench.import_verification import run

        record = run(quick=quick, capture=capture, repeats=repeats, width_px=width, emit_json=json_out)
        if not json_out:
            typer.echo(f"import {record['before_s']:.2f} s without full verification, {record['after_s']:.2f} s "
                       f"with it (verification {record['verify_s']:.2f} s, {record['verify_one_thread_s']:.2f} s "
                       f"in one thread; {record['files_verified']} files, {record['capture_mb']} MB)")
