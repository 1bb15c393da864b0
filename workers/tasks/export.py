"""The admin page's FreiHAND export (services.exports.export_jobs): write the accepted samples in FreiHAND's layout
into a scratch folder next to storage, zip it into storage under services.exports.export_jobs.archive_key, and report
the progress on the job row (writing: 0-90 %, packing: 90-100 %)."""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

from backend.models.enums import JobState
from backend.services.errors import DomainError
from backend.services.exports import export, export_jobs
from backend.services.jobs import jobs
from backend.services.review import label_audits
from workers.export.freihand import ExportError, ExportOptions, write_freihand
from workers.export.hand_models import export_hand_models
from workers.tasks.context import WorkerContext
from workers.tasks.progress import JobCancelledError, ProgressReporter


def run_freihand_export_job(ctx: WorkerContext, job_id: int) -> dict[str, Any]:
    """Claim an export job (payload: up_to_round, project, composites, meshes) and run it; returns its result
    (also stored on the job): the archive's storage key and size, and the export's summary."""
    with ctx.session_factory.begin() as session:
        job = ctx.claim(session, job_id)
        if job is None:
            return {"job_id": job_id, "skipped": True}
        payload = dict(job.payload or {})
        try:
            records = export.export_records(session, payload.get("up_to_round"), payload.get("project"))
            quality = label_audits.summary(session)
        except DomainError as exc:
            jobs.finish(session, job_id, JobState.failed, error=exc.message[:2000])
            return {"job_id": job_id, "failed": exc.message}
    meshes = str(payload.get("meshes", "ply"))
    formats = () if meshes == "none" else tuple(p for p in meshes.split(",") if p)
    reporter = ProgressReporter(ctx, [job_id])
    key = export_jobs.archive_key(job_id)
    archive = ctx.storage_path(key)
    archive.parent.mkdir(parents=True, exist_ok=True)
    done = 0

    def wrote(n: int) -> None:
        nonlocal done
        done += n
        reporter(0.9 * done / max(1, len(records)), f"writing {done}/{len(records)} samples")

    try:
        options = ExportOptions(composites=int(payload.get("composites", 0)), mesh_formats=formats)
        arrays, left = export_hand_models(ctx.settings.mano_path, records)
        reporter(0.0, f"writing 0/{len(records)} samples", force=True)
        with tempfile.TemporaryDirectory(dir=archive.parent, prefix=f"job-{job_id}-") as scratch:
            out = Path(scratch) / "freihand"
            summary = write_freihand(records, out, ctx.storage.get_bytes, arrays, options, progress=wrote,
                                     other_side=left, label_quality=quality)
            reporter(0.9, "packing the archive", force=True)
            _zip(out, archive)
    except (ExportError, DomainError) as exc:
        message = getattr(exc, "message", None) or str(exc)
        with ctx.session_factory.begin() as session:
            jobs.finish(session, job_id, JobState.failed, error=message[:2000])
        return {"job_id": job_id, "failed": message}
    except JobCancelledError:
        archive.unlink(missing_ok=True)
        return {"job_id": job_id, "cancelled": True}
    result = {"archive": key, "bytes": archive.stat().st_size, "hand_model": summary.hand_model,
              "is_mano": summary.is_mano, "samples": summary.samples, "images": summary.images,
              "multi_view_samples": summary.multi_view_samples}
    with ctx.session_factory.begin() as session:
        jobs.finish(session, job_id, JobState.succeeded, result=result)
    return result


def _zip(folder: Path, archive: Path) -> None:
    """`folder`'s files under its own name in `archive`, written whole (a partial archive is never seen)."""
    part = archive.with_name(archive.name + ".part")
    with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                z.write(path, Path(folder.name) / path.relative_to(folder))
    shutil.move(part, archive)
