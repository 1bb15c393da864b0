"""`handloop export --format freihand --out DIR`: the accepted dataset in FreiHAND's layout."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

FORMATS = ("freihand",)


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("export")
    def export(
        out: Path = typer.Option(..., "--out", help="Folder to create (absent or empty, unless --force)."),
        fmt: str = typer.Option("freihand", "--format", help="Output layout: freihand."),
        up_to_round: int | None = typer.Option(None, min=0, help="Only D_i up to this round index."),
        project: str | None = typer.Option(None, help="Only this project's samples."),
        composites: int = typer.Option(0, help="Cut&Paste versions per green-screen training image (0-8)."),
        meshes: str = typer.Option("ply", help="Mesh files per fitted sample: ply, obj, ply,obj or none."),
        seed: int = typer.Option(0, help="Seeds the composites' backgrounds."),
        jpeg_quality: int = typer.Option(95, help="JPEG quality of images and masks (50-100)."),
        force: bool = typer.Option(False, "--force", help="Replace a non-empty output folder."),
        json_out: bool = typer.Option(False, "--json", help="Print a JSON summary as the last stdout line."),
    ) -> None:
        """Write the accepted samples' fits in FreiHAND's layout: training_/evaluation_ K, mano, xyz, scale
        and verts files, rgb/ and mask/ images (one sample per view, camera frame), meshes, a manifest, and
        which hand model made the labels."""
        from tqdm import tqdm

        from backend.db.session import create_engine_from_url, make_session_factory
        from backend.services.captures.storage import LocalDiskStorage
        from backend.services.errors import DomainError
        from backend.services.exports.export import export_records
        from backend.services.review.label_audits import summary as quality_summary
        from backend.settings import get_settings
        from workers.export.freihand import ExportError, ExportOptions, hand_model_notice, write_freihand
        from workers.export.hand_models import export_hand_models

        def fail(message: str) -> None:
            typer.echo(f"error: {message}", err=True)
            raise typer.Exit(code=2)

        if fmt not in FORMATS:
            fail(f"--format must be one of {', '.join(FORMATS)}, not {fmt!r}")
        formats = () if meshes == "none" else tuple(part.strip() for part in meshes.split(",") if part.strip())
        try:
            options = ExportOptions(composites=composites, mesh_formats=formats, jpeg_quality=jpeg_quality,
                                    seed=seed, force=force)
        except ExportError as exc:
            fail(str(exc))
        settings = get_settings()
        engine = create_engine_from_url(settings.resolved_database_url)
        try:
            with make_session_factory(engine)() as session:
                records = export_records(session, up_to_round, project)
                quality = quality_summary(session)
        except DomainError as exc:
            fail(exc.message)
        finally:
            engine.dispose()
        # Left hands' fits pose the left model (a MANO folder then needs MANO_LEFT.pkl too).
        try:
            arrays, left = export_hand_models(settings.mano_path, records)
        except ExportError as exc:
            fail(str(exc))
        typer.echo(hand_model_notice(arrays), err=True)
        storage = LocalDiskStorage(settings.storage_dir)
        try:
            with tqdm(total=len(records), unit="sample", desc="exporting", file=sys.stderr) as bar:
                summary = write_freihand(records, out, storage.get_bytes, arrays, options, progress=bar.update,
                                         other_side=left, label_quality=quality)
        except (ExportError, DomainError) as exc:
            fail(getattr(exc, "message", None) or str(exc))
        result = {"out": str(summary.out_dir), "hand_model": summary.hand_model, "is_mano": summary.is_mano,
                  "samples": summary.samples, "images": summary.images,
                  "multi_view_samples": summary.multi_view_samples, "meshes": summary.meshes}
        if json_out:
            sys.stdout.write(json.dumps(result) + "\n")
        else:
            typer.echo(f"wrote {summary.samples['training']} training and {summary.samples['evaluation']} "
                       f"evaluation samples ({summary.multi_view_samples} multi-view samples) to {summary.out_dir}")
