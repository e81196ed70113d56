"""The flow renderer of Paper A (Sec. A.3.2): the optical flow a mesh's motion would cause,
rendered in place.

For frame i the mesh is rasterised at its frame-i vertices; each covered pixel sees a surface
point with barycentric coordinates ``b`` in its triangle. The *backward* flow (frame i → i − 1)
at that pixel is where the same surface point lies in frame i − 1, minus where it lies in
frame i, both projected by the camera:

    F_r(i, i−1, p) = π(Σ_k b_k v_k^{i−1}) − π(Σ_k b_k v_k^{i})

The dissertation interpolates the vertices' projected 2D displacements barycentrically; here
the 3D points are interpolated first and then projected, which is exact under perspective for
a surface that moves linearly within each triangle (rigid or skinned) and costs the same. The
result is differentiable with respect to both vertex sets, with visibility and barycentric
coordinates held fixed (those of frame i's rasterisation). The flow-matching energy (Eq. A.1)
compares it with the observed flow on the covered pixels: :func:`flow_energy`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from monoavatar.core.camera import PinholeCamera
from monoavatar.core.geometry import float_tensor
from monoavatar.render.interpolate import interpolate_masked, scatter_masked
from monoavatar.render.raster import Fragments, rasterize

__all__ = ["RenderedFlow", "flow_energy", "render_flow"]


@dataclass(frozen=True)
class RenderedFlow:
    """A rendered backward flow.

    Attributes:
        flow: (H, W, 2) pixels (x, y), from frame i to frame i − 1; zero where nothing is seen.
        mask: (H, W) bool, the pixels the mesh covers in frame i.
        fragments: frame i's rasterisation (visibility and barycentrics held fixed).
    """

    flow: Tensor
    mask: Tensor
    fragments: Fragments


def render_flow(
    vertices: Tensor | np.ndarray,
    previous: Tensor | np.ndarray,
    faces: Tensor | np.ndarray,
    camera: PinholeCamera,
    fragments: Fragments | None = None,
) -> RenderedFlow:
    """Render the backward flow of a mesh moving from ``previous`` to ``vertices``.

    Args:
        vertices: (V, 3) world metres, frame i (the frame whose pixels the flow is drawn on).
        previous: (V, 3) world metres, the same vertices in frame i − 1.
        faces: (F, 3) vertex indices.
        camera: the (static) camera of both frames.
        fragments: frame i's rasterisation, when already at hand (else rasterised here).
    Returns:
        :class:`RenderedFlow`; ``flow`` carries gradients to both vertex sets.
    Raises:
        ValueError: the two vertex sets differ in shape.
    """
    v = float_tensor(vertices, "vertices", 3)
    p = float_tensor(previous, "previous", 3).to(v.dtype)
    if v.shape != p.shape:
        raise ValueError(f"vertices {tuple(v.shape)} and previous {tuple(p.shape)} differ")
    frags = fragments if fragments is not None else rasterize(v.detach(), faces, camera)
    now_px, _ = camera.project(interpolate_masked(v, faces, frags))
    before_px, _ = camera.project(interpolate_masked(p, faces, frags))
    flow = scatter_masked(before_px - now_px, frags)
    return RenderedFlow(flow=flow, mask=frags.face_id >= 0, fragments=frags)


def flow_energy(rendered: RenderedFlow, observed: Tensor | np.ndarray,
                valid: Tensor | np.ndarray | None = None) -> Tensor:
    """Eq. A.1: ``Σ_p |F_o(p) − F_r(p)|²`` over the pixels the mesh covers (and ``valid``
    marks, e.g. where the observed flow is trusted).

    Args:
        rendered: the rendered backward flow.
        observed: (H, W, 2) the observed backward flow (frame i → i − 1), pixels.
        valid: optional (H, W) bool.
    Returns:
        () the energy, pixels², differentiable through ``rendered.flow``.
    """
    flow = rendered.flow
    obs = torch.as_tensor(observed, dtype=flow.dtype)
    if obs.shape != flow.shape:
        raise ValueError(f"observed flow must have shape {tuple(flow.shape)}, "
                         f"got {tuple(obs.shape)}")  # fmt: skip
    mask = rendered.mask
    if valid is not None:
        mask = mask & torch.as_tensor(valid, dtype=torch.bool)
    return ((obs - flow)[mask] ** 2).sum()
