"""Capture import: validate with the capture reader, verify every file in full (each image and mask decoded,
each ground-truth .npz loaded and its arrays checked: workers.capture.verify), then create the project's rows
and copy images and chroma-key masks into storage. Validation and verification come before anything is
written, and the rows are one transaction: a capture with a broken file writes nothing."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Project, Sample, Sequence, Subject, View
from backend.models.enums import MaskKind, SampleState
from backend.models.labels import Mask
from backend.schemas.admin import ImportPublic
from backend.services import audit
from backend.services.captures.storage import Storage
from backend.services.errors import ConflictError, InvalidInputError

logger = logging.getLogger(__name__)


def check_import_path(path: Path, roots: list[Path]) -> Path:
    """The capture folder an API import names, resolved, when it lies inside one of `roots` (resolved folders);
    InvalidInputError naming the roots otherwise. A relative path is refused rather than read against the
    server's working folder."""
    where = ", ".join(str(r) for r in roots)
    if not path.is_absolute():
        raise InvalidInputError(f"path {str(path)!r} is relative; give the capture folder's absolute path, inside "
                                f"one of the import roots: {where}")
    resolved = path.resolve()
    if not any(resolved.is_relative_to(root) for root in roots):
        raise InvalidInputError(f"{path} is outside the import roots ({where}); put the capture under one of them, "
                                "or have the server's admin add its folder to HANDLOOP_IMPORT_ROOTS")
    return resolved


def check_contained(capture: Any) -> None:
    """Every file of the capture lies inside its folder: a sequence folder or a file linked to elsewhere on the
    server (a symbolic link) is refused, so an import reads only what was put under an import root."""
    root = Path(capture.root).resolve()
    for sequence in capture.sequences:
        for frame in sequence.frames:
            paths = [*frame.image_paths.values(), *frame.mask_paths.values(), *frame.gt_mask_paths.values(),
                     frame.ground_truth_path]
            for path in paths:
                if path is not None and not Path(path).resolve().is_relative_to(root):
                    raise InvalidInputError(f"capture rejected, nothing was imported: {path} leads outside the "
                                            f"capture folder {root} (a symbolic link); copy the files into it")


def import_capture(session: Session, storage: Storage, path: Path, *, project_name: str | None = None,
                   queue_for_annotation: bool = True, actor_id: int | None = None,
                   progress: Callable[[int, int], None] | None = None) -> ImportPublic:
    """Import the capture at `path` as a new project; samples start 'needs_annotation' (round 0's queue)
    or 'unlabeled'. `progress(files verified, files in all)` is called during the verification."""
    # deferred: the capture reader pulls in cv2 and PIL; the API's start-up imports this module
    from workers.capture import CaptureError, read_capture
    from workers.capture.verify import verify_capture_files

    try:
        capture = read_capture(path)
    except CaptureError as exc:
        raise InvalidInputError(f"capture rejected: {exc}") from exc
    check_contained(capture)
    name = project_name or capture.name
    if session.execute(select(Project.id).where(Project.name == name)).first() is not None:
        raise ConflictError(f"a project named {name!r} already exists; pass another project name")
    try:
        verify_capture_files(capture, progress=progress)
    except CaptureError as exc:
        raise InvalidInputError(f"capture rejected, nothing was imported: {exc}") from exc
    return write_project(session, storage, capture, name, queue_for_annotation=queue_for_annotation,
                         actor_id=actor_id, source=path)


def write_project(session: Session, storage: Storage, capture: Any, name: str, *, queue_for_annotation: bool = True,
                  actor_id: int | None = None, source: Path | None = None) -> ImportPublic:
    """The rows and stored files of a capture already read and verified (`import_capture`'s last step, timed
    alone by `handloop bench verify`). `capture`: a workers.capture.Capture."""
    project = Project(name=name, hand_model=capture.hand_model.name, synthetic=capture.synthetic,
                      description=f"imported from {capture.root}", working_width_px=capture.working_width_px)
    session.add(project)
    session.flush()
    cameras = {}
    for cam in capture.cameras:
        row = CameraCalibration(project_id=project.id, name=cam.name, width=cam.width, height=cam.height,
                                K=cam.K.tolist(), dist=cam.dist.tolist(), R=cam.R.tolist(), t=cam.t.tolist())
        session.add(row)
        cameras[cam.name] = row
    subjects = {}
    for sid in capture.subjects:
        subjects[sid] = Subject(project_id=project.id, external_id=sid)
        session.add(subjects[sid])
    session.flush()
    state = SampleState.needs_annotation if queue_for_annotation else SampleState.unlabeled
    prefix = f"captures/{project.id}"
    n_samples = n_views = n_masks = 0
    for seq in capture.sequences:
        seq_row = Sequence(project_id=project.id, subject_id=subjects[seq.subject_id].id, external_id=seq.id,
                           split=seq.split, green_screen=seq.green_screen, fps=seq.fps,
                           holds_object=seq.holds_object, side=seq.hand_side or capture.hand_model.side)
        session.add(seq_row)
        session.flush()
        for frame in seq.frames:
            gt_key = None
            if frame.ground_truth_path is not None:
                gt_key = f"{prefix}/{seq.id}/ground_truth/{frame.ground_truth_path.name}"
                storage.put_file(gt_key, frame.ground_truth_path)
            sample = Sample(sequence_id=seq_row.id, frame_index=frame.index, time_s=frame.time_s, split=seq.split,
                            green_screen=seq.green_screen, ground_truth_key=gt_key, state=state)
            session.add(sample)
            session.flush()
            n_samples += 1
            for cam in capture.cameras:
                image = frame.image_paths[cam.name]
                key = f"{prefix}/{seq.id}/images/{cam.name}/{image.name}"
                storage.put_file(key, image)
                view = View(sample_id=sample.id, camera_id=cameras[cam.name].id, image_key=key, width=cam.width,
                            height=cam.height)
                session.add(view)
                n_views += 1
                mask_path = frame.mask_paths.get(cam.name)
                if mask_path is not None:
                    session.flush()
                    mask_key = f"{prefix}/{seq.id}/masks/{cam.name}/{mask_path.name}"
                    storage.put_file(mask_key, mask_path)
                    session.add(Mask(view_id=view.id, kind=MaskKind.chroma_key, version=1, storage_key=mask_key,
                                     created_by_id=actor_id))
                    n_masks += 1
    audit.record(session, actor_id, "project.import", "project", project.id, path=str(source or capture.root),
                 samples=n_samples)
    logger.info("imported %s: %d samples, %d views, %d masks", name, n_samples, n_views, n_masks)
    return ImportPublic(project_id=project.id, project=name, cameras=len(cameras), sequences=len(capture.sequences),
                        samples=n_samples, views=n_views, masks=n_masks)
