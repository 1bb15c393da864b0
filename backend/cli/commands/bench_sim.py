"""`handloop bench sim`: the bootstrap simulation against the issue's targets (docs/benchmarks.md)."""

from __future__ import annotations

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @bench.command("sim")
    def bench_sim(
        json_out: bool = typer.Option(False, "--json", help="Print the JSON record as the last stdout line."),
        quick: bool = typer.Option(False, "--quick", help="Reduced run (tiny networks, 24 frames, 1 round)."),
    ) -> None:
        """200-frame synthetic capture, cpu-small networks, 4 rounds through the real server and workers:
        minutes, accepted labels' vertex error, auto-accept precision, labels per human hour."""
        import logging

        from backend.bench.sim import run

        logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request drowns the progress
        record = run(quick=quick, emit_json=json_out)
        if not json_out:
            for r in record["rounds"]:
                typer.echo(f"D_{r['index']}: {r['dataset_size']} samples, {r['human_hours']:.2f} h")
            typer.echo(f"minutes {record['minutes']:.1f}  accepted {record['accepted_vertex_mm']} mm  "
                       f"auto-accept precision {record['auto_accept_precision']}  "
                       f"labels/h {record['labels_per_human_hour']}")
