"""Texture stage (Sec. B.3.4, C.3.4): back-projection of key frames onto the UV layout, merged
by the median of the most orthogonal views or by semantic graph cuts, seam-aware hole filling,
and SH lighting estimation for albedo."""

from monoavatar.texture.atlas import (
    TexelAtlas,
    TextureError,
    build_atlas,
    seam_edges,
    texel_graph,
)
from monoavatar.texture.backproject import (
    TextureSettings,
    UVTexture,
    build_texture,
    sampling_size,
)
from monoavatar.texture.fill import dilate_texture, harmonic_fill
from monoavatar.texture.graphcut import GraphCutSettings, merge_views
from monoavatar.texture.lighting import estimate_sh, fit_sh

__all__ = [
    "GraphCutSettings",
    "TexelAtlas",
    "TextureError",
    "TextureSettings",
    "UVTexture",
    "build_atlas",
    "build_texture",
    "dilate_texture",
    "estimate_sh",
    "fit_sh",
    "harmonic_fill",
    "merge_views",
    "sampling_size",
    "seam_edges",
    "texel_graph",
]
