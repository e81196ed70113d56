"""CPU rendering: rasterisation, attribute interpolation, SH shading and convenience renders.

Deferred, OpenDR-style: :func:`rasterize` fixes visibility in :class:`Fragments` (face ids,
perspective-correct barycentrics, depth); :func:`interpolate` and the ``render_*`` functions
compute per-pixel values from them, differentiably in the attribute values;
:func:`render_flow` renders the optical flow of a moving mesh (Paper A's flow renderer).

Conventions: OpenCV pinhole cameras (:class:`monoavatar.core.camera.PinholeCamera`), pixel centres
at (col + 0.5, row + 0.5), metres, glTF UVs ((0, 0) = top-left of the texture, v down).
"""

from monoavatar.render.flow import RenderedFlow, flow_energy, render_flow
from monoavatar.render.interpolate import interpolate, interpolate_masked, scatter_masked
from monoavatar.render.raster import (
    Fragments,
    RasterSettings,
    fragments_from_face_ids,
    rasterize,
)
from monoavatar.render.renders import (
    render_depth,
    render_face_labels,
    render_normals,
    render_over_image,
    render_silhouette,
    render_textured,
    render_uv,
    render_vertex_labels,
    sample_texture,
    vertex_normals,
)
from monoavatar.render.shading import (
    SH_BAND_FACTORS,
    SampledLighting,
    directional_light_sh,
    sample_sh_lighting,
    sh_basis,
    sh_irradiance,
    sh_shading,
)

__all__ = [
    "SH_BAND_FACTORS",
    "Fragments",
    "RenderedFlow",
    "RasterSettings",
    "SampledLighting",
    "directional_light_sh",
    "flow_energy",
    "fragments_from_face_ids",
    "interpolate",
    "interpolate_masked",
    "rasterize",
    "render_depth",
    "render_face_labels",
    "render_flow",
    "render_normals",
    "render_over_image",
    "render_silhouette",
    "render_textured",
    "render_uv",
    "render_vertex_labels",
    "sample_sh_lighting",
    "sample_texture",
    "scatter_masked",
    "sh_basis",
    "sh_irradiance",
    "sh_shading",
    "vertex_normals",
]
