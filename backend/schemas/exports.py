"""Admin: the FreiHAND export job's request and answer."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from backend.schemas.base import Public, Strict


class FreihandExportCreate(Strict):
    up_to_round: int | None = Field(default=None, ge=0, le=1_000_000, description="Only D_i up to this round.")
    project: str | None = Field(default=None, min_length=1, max_length=200, pattern=r"^[^\x00]*$",
                                description="Only this project's samples.")
    composites: int = Field(default=0, ge=0, le=8, description="Cut&Paste versions per green-screen training image.")
    meshes: Literal["ply", "obj", "ply,obj", "none"] = Field(default="ply", description="Mesh files per sample.")


class ExportQueued(Public):
    job_id: int
    samples: int = Field(description="Accepted samples the export will write.")
