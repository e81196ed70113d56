"""The body-model interface every stage uses (SMPL+D, Eq. 3.3–3.4), with posing and unposing.

A back-end (Anny, SMPL) supplies, in the canonical frame (Y up, facing +Z, metres; rest pose =
the model's zero pose):

- ``rest_shape(shape) -> (vertices (B, V, 3), joints (B, J, 3))``: template + shape blend shapes;
- optionally ``pose_correctives(rotations) -> (B, V, 3)``: pose-dependent offsets B_p(θ);
- buffers: ``faces (F, 3)``, ``uv (T, 2)`` with ``face_uv (F, 3)`` (separate UV indexing, glTF
  convention: origin at the top-left of the texture image, v downwards), ``skin_weights (V, J)``,
  ``regions (V,)`` (indices into :data:`REGIONS`), ``mirror (V,)`` (index of the left/right
  symmetric vertex), ``keypoint_weights (33, V)`` with ``keypoint_valid (33,)`` for mediapipe's
  33 pose landmarks.

Everything here is batched and differentiable in PyTorch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from monoavatar.body import lbs
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.landmarks import COCO17_IN_MEDIAPIPE, MEDIAPIPE_LANDMARKS

#: Per-vertex region labels, for per-vertex regularisation weights (Sec. B.3.3).
REGIONS: tuple[str, ...] = ("torso", "face", "hair", "arms", "hands", "legs", "feet")

__all__ = [
    "COCO17_IN_MEDIAPIPE",
    "MEDIAPIPE_LANDMARKS",
    "REGIONS",
    "BodyModel",
    "BodyModelError",
    "BodyOutput",
]


class BodyModelError(MonoavatarError, ValueError):
    """Bad input to a body model: wrong shapes, unknown names, missing or corrupt files."""


@dataclass
class BodyOutput:
    """Result of posing a body.

    Attributes:
        vertices: (B, V, 3) posed vertices, world frame, metres.
        joints: (B, J, 3) posed joint positions.
        transforms: (B, J, 4, 4) rest → posed joint transforms (global translation included).
        rest_vertices: (B, V, 3) canonical vertices T(β, θ, D) (shape + correctives + offsets).
        rest_joints: (B, J, 3) canonical joint positions.
        correctives: (B, V, 3) pose-dependent offsets B_p(θ) (zeros when the model has none).
    """

    vertices: Tensor
    joints: Tensor
    transforms: Tensor
    rest_vertices: Tensor
    rest_joints: Tensor
    correctives: Tensor


def _check(name: str, tensor: Tensor, shape: Sequence[int | None]) -> None:
    """Raise BodyModelError unless ``tensor.shape`` matches ``shape`` (None = any size)."""
    ok = tensor.dim() == len(shape) and all(
        s is None or s == t for s, t in zip(shape, tensor.shape, strict=True)
    )
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise BodyModelError(f"{name}: expected shape {want}, got {tuple(tensor.shape)}")


class BodyModel(nn.Module):
    """Base class of body-model back-ends. Subclasses set the buffers listed in the module
    docstring in ``__init__`` and implement :meth:`rest_shape`."""

    faces: Tensor
    uv: Tensor
    face_uv: Tensor
    skin_weights: Tensor
    regions: Tensor
    mirror: Tensor
    keypoint_weights: Tensor
    keypoint_valid: Tensor

    #: Identity of the back-end, saved with avatars (e.g. "anny-0.6.2", "smpl:neutral").
    identity: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    shape_names: tuple[str, ...]

    # -- sizes ----------------------------------------------------------------------------
    @property
    def num_vertices(self) -> int:
        return int(self.skin_weights.shape[0])

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def shape_dim(self) -> int:
        return len(self.shape_names)

    @property
    def dtype(self) -> torch.dtype:
        return self.skin_weights.dtype

    @property
    def device(self) -> torch.device:
        return self.skin_weights.device

    def joint_index(self, name: str) -> int:
        """Index of a joint by name; unknown names raise with the list of valid ones."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise BodyModelError(
                f"unknown joint {name!r}; this model's joints are {list(self.joint_names)}"
            ) from None

    def default_shape(self, batch: int = 1) -> Tensor:
        """(B, S) shape parameters of an average body."""
        return torch.zeros(batch, self.shape_dim, dtype=self.dtype, device=self.device)

    def zero_pose(self, batch: int = 1) -> Tensor:
        """(B, J, 3) axis-angle rest pose."""
        return torch.zeros(batch, self.num_joints, 3, dtype=self.dtype, device=self.device)

    # -- back-end hooks ---------------------------------------------------------------------
    def rest_shape(self, shape: Tensor) -> tuple[Tensor, Tensor]:
        """shape (B, S) → rest vertices (B, V, 3), rest joints (B, J, 3), canonical frame."""
        raise NotImplementedError

    def pose_correctives(self, rotations: Tensor) -> Tensor | None:
        """rotations (B, J, 3, 3) → (B, V, 3) pose-dependent offsets, or None if the model has
        none (Anny)."""
        return None

    # -- posing -----------------------------------------------------------------------------
    def rotations_from(self, pose: Tensor) -> Tensor:
        """Accept (B, J, 3) axis-angle or (B, J, 3, 3) matrices; return (B, J, 3, 3)."""
        if pose.dim() == 3:
            _check("pose", pose, (None, self.num_joints, 3))
            return lbs.axis_angle_to_matrix(pose)
        _check("pose", pose, (None, self.num_joints, 3, 3))
        return pose

    def forward(
        self,
        shape: Tensor | None = None,
        pose: Tensor | None = None,
        translation: Tensor | None = None,
        offsets: Tensor | None = None,
    ) -> BodyOutput:
        """Pose the body (SMPL+D, Eq. 3.3–3.4).

        Args:
            shape: (B, S) shape parameters, or None for the average body (B from pose).
            pose: (B, J, 3) axis-angle (radians) or (B, J, 3, 3) rotation matrices, local to
                each joint in canonical axes; joint 0 is the global orientation. None = rest.
            translation: (B, 3) metres, or None.
            offsets: per-vertex offsets D in canonical space, (V, 3) or (B, V, 3), or None.
        Returns:
            :class:`BodyOutput`.
        """
        batch = 1
        for value in (shape, pose, translation):
            if value is not None:
                batch = max(batch, value.shape[0])
        if shape is None:
            shape = self.default_shape(batch)
        _check("shape", shape, (None, self.shape_dim))
        rotations = (
            self.rotations_from(pose)
            if pose is not None
            else lbs.axis_angle_to_matrix(self.zero_pose(batch))
        )
        if translation is not None:
            _check("translation", translation, (None, 3))
        if offsets is not None:
            if offsets.dim() == 2:
                _check("offsets", offsets, (self.num_vertices, 3))
            else:
                _check("offsets", offsets, (None, self.num_vertices, 3))
        sizes = {shape.shape[0], rotations.shape[0]}
        if translation is not None:
            sizes.add(translation.shape[0])
        if len(sizes - {1}) > 1:
            raise BodyModelError(f"batch sizes disagree: {sorted(sizes)}")

        rest_vertices, rest_joints = self.rest_shape(shape)
        rest_vertices = rest_vertices.expand(batch, -1, -1)
        rest_joints = rest_joints.expand(batch, -1, -1)
        rotations = rotations.expand(batch, -1, -1, -1)
        correctives = self.pose_correctives(rotations)
        if correctives is None:
            correctives = torch.zeros_like(rest_vertices)
        canonical = rest_vertices + correctives
        if offsets is not None:
            canonical = canonical + offsets
        if translation is not None:
            translation = translation.expand(batch, -1)
        transforms = lbs.joint_transforms(rotations, rest_joints, self.parents, translation)
        vertices = lbs.skin(canonical, self.skin_weights, transforms)
        joints = transforms[..., :3, 3] + (
            transforms[..., :3, :3] @ rest_joints.unsqueeze(-1)
        ).squeeze(-1)
        return BodyOutput(
            vertices=vertices,
            joints=joints,
            transforms=transforms,
            rest_vertices=canonical,
            rest_joints=rest_joints,
            correctives=correctives,
        )

    # -- unposing (Eq. B.6) -------------------------------------------------------------------
    def vertex_transforms(self, transforms: Tensor, vertex_ids: Tensor) -> Tensor:
        """Blended transforms of given vertices.

        Args:
            transforms: (B, J, 4, 4) from :meth:`forward`.
            vertex_ids: (N,) or (B, N) vertex indices.
        Returns:
            (B, N, 4, 4).
        """
        return lbs.blend_transforms(self.skin_weights[vertex_ids], transforms)

    @staticmethod
    def _gather_correctives(correctives: Tensor | None, vertex_ids: Tensor) -> Tensor | None:
        if correctives is None:
            return None
        if vertex_ids.dim() == 1:
            return correctives[:, vertex_ids]
        return torch.gather(correctives, 1, vertex_ids.unsqueeze(-1).expand(-1, -1, 3))

    def unpose_points(
        self,
        points: Tensor,
        vertex_ids: Tensor,
        transforms: Tensor,
        correctives: Tensor | None = None,
    ) -> Tensor:
        """Bring posed points attached to vertices back to the canonical pose (Eq. B.6):
        ``x = (Σ_k w_ik A_k)⁻¹ x' − b_P,i``.

        Args:
            points: (B, N, 3) posed points; vertex_ids: (N,) or (B, N) their vertices;
            transforms: (B, J, 4, 4); correctives: (B, V, 3) B_p(θ) or None.
        Returns:
            (B, N, 3) canonical points.
        """
        inverse = lbs.invert_affine(self.vertex_transforms(transforms, vertex_ids))
        canonical = lbs.transform_points(inverse, points)
        corr = self._gather_correctives(correctives, vertex_ids)
        return canonical if corr is None else canonical - corr

    def pose_points(
        self,
        points: Tensor,
        vertex_ids: Tensor,
        transforms: Tensor,
        correctives: Tensor | None = None,
    ) -> Tensor:
        """The inverse of :meth:`unpose_points`: canonical points attached to vertices → posed."""
        corr = self._gather_correctives(correctives, vertex_ids)
        if corr is not None:
            points = points + corr
        return lbs.transform_points(self.vertex_transforms(transforms, vertex_ids), points)

    def unpose_directions(
        self, directions: Tensor, vertex_ids: Tensor, transforms: Tensor
    ) -> Tensor:
        """Posed directions (B, N, 3) → canonical, by the inverse linear part (unit length out)."""
        inverse = lbs.invert_affine(self.vertex_transforms(transforms, vertex_ids))
        d = lbs.transform_directions(inverse, directions)
        return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def unpose_normals(self, normals: Tensor, vertex_ids: Tensor, transforms: Tensor) -> Tensor:
        """Posed normals (B, N, 3) → canonical: ``n = Lᵀ n'`` renormalised (inverse transpose
        of the inverse)."""
        blended = self.vertex_transforms(transforms, vertex_ids)
        n = (blended[..., :3, :3].transpose(-1, -2) @ normals.unsqueeze(-1)).squeeze(-1)
        return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def pose_normals(self, normals: Tensor, vertex_ids: Tensor, transforms: Tensor) -> Tensor:
        """Canonical normals (B, N, 3) → posed, by the inverse transpose."""
        return lbs.transform_normals(self.vertex_transforms(transforms, vertex_ids), normals)

    def unpose_rays(
        self,
        origins: Tensor,
        directions: Tensor,
        vertex_ids: Tensor,
        transforms: Tensor,
        correctives: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Unpose rays attached to vertices (Eq. B.6, Fig. B.3).

        Each ray is mapped by the inverse blended transform of its vertex, an affine map, so
        lines stay lines. Args: origins, directions (B, N, 3) posed; vertex_ids (N,) or (B, N).
        Returns canonical (origins, unit directions), (B, N, 3) each; use
        :func:`monoavatar.core.camera.plucker` for Plücker coordinates.
        """
        canonical_origins = self.unpose_points(origins, vertex_ids, transforms, correctives)
        return canonical_origins, self.unpose_directions(directions, vertex_ids, transforms)

    # -- keypoints ------------------------------------------------------------------------------
    def keypoints(self, vertices: Tensor) -> Tensor:
        """vertices (B, V, 3) → (B, 33, 3) mediapipe landmarks (zeros where
        ``keypoint_valid`` is False)."""
        _check("vertices", vertices, (None, self.num_vertices, 3))
        return torch.einsum("kv,bvc->bkc", self.keypoint_weights, vertices)
