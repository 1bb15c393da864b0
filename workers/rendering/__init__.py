"""CPU rendering: a vectorised z-buffer rasterizer, smooth Lambert shading, multi-part scenes."""

from workers.rendering.rasterizer import Fragments, coverage_mask, model_mask, rasterize, rasterize_projected
from workers.rendering.scene import MeshPart, ViewRender, merge_parts, render_views
from workers.rendering.shading import (
    DirectionalLight,
    ShadingSettings,
    interpolate,
    shade,
    shade_vertices,
    vertex_normals,
)

__all__ = [
    "DirectionalLight",
    "Fragments",
    "MeshPart",
    "ShadingSettings",
    "ViewRender",
    "coverage_mask",
    "interpolate",
    "merge_parts",
    "model_mask",
    "rasterize",
    "rasterize_projected",
    "render_views",
    "shade",
    "shade_vertices",
    "vertex_normals",
]
