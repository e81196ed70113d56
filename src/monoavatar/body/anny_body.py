"""Anny (PyPI ``anny``, Apache-2.0, CC0 assets) behind the :class:`BodyModel` interface.

Anny's native frame is Z-up with the body facing -Y; ours is Y-up facing +Z. The conversion is
the rotation ``C`` (x, y, z) → (x, z, -y), applied once here, to vertices and joints.

Shape parameters (B, S):
- ``shape[:, :6]`` = Anny's phenotypes (gender, age, muscle, weight, height, proportions) minus
  0.5, so that zeros give Anny's average body (each phenotype lies in [0, 1]);
- ``shape[:, 6:]`` = Anny's local changes (when enabled), weights in about [-1, 1], 0 = none.

Skeleton: Anny's 104-bone rig is reduced to a 20-joint fitting skeleton (SMPL's main joints,
:data:`FIT_JOINTS`). Bones outside it (fingers, toes, eyes, twist and spine sub-bones) ride
rigidly with their nearest fitting ancestor; their skinning weights are summed into that
ancestor, which is exact for linear blend skinning when those bones keep their rest
orientation relative to the ancestor.
"""

from __future__ import annotations

import importlib.metadata
import warnings
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import labels
from monoavatar.body.model import MEDIAPIPE_LANDMARKS, BodyModel, BodyModelError

#: Our fitting joints and the Anny bone each one is, parents before children.
FIT_JOINTS: tuple[tuple[str, str], ...] = (
    ("pelvis", "root"),
    ("spine1", "spine04"),
    ("spine2", "spine02"),
    ("spine3", "spine01"),
    ("neck", "neck01"),
    ("head", "head"),
    ("collar_l", "clavicle.L"),
    ("shoulder_l", "upperarm01.L"),
    ("elbow_l", "lowerarm01.L"),
    ("wrist_l", "wrist.L"),
    ("collar_r", "clavicle.R"),
    ("shoulder_r", "upperarm01.R"),
    ("elbow_r", "lowerarm01.R"),
    ("wrist_r", "wrist.R"),
    ("hip_l", "upperleg01.L"),
    ("knee_l", "lowerleg01.L"),
    ("ankle_l", "foot.L"),
    ("hip_r", "upperleg01.R"),
    ("knee_r", "lowerleg01.R"),
    ("ankle_r", "foot.R"),
)

PHENOTYPES: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")

#: Anny frame (Z up, facing -Y) → ours (Y up, facing +Z).
ANNY_TO_CANONICAL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

_REGION_OF_BONE_PREFIX: tuple[tuple[str, str], ...] = (
    ("finger", "hands"),
    ("metacarpal", "hands"),
    ("wrist", "hands"),
    ("toe", "feet"),
    ("foot", "feet"),
    ("upperarm", "arms"),
    ("lowerarm", "arms"),
    ("shoulder", "arms"),
    ("upperleg", "legs"),
    ("lowerleg", "legs"),
    ("head", "head"),
    ("eye", "head"),
)


def _anny_version() -> str:
    try:
        return importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover
        return "unknown"


def _region_of_bone(label: str) -> str:
    for prefix, name in _REGION_OF_BONE_PREFIX:
        if label.startswith(prefix):
            return name
    return "torso"


def _fit_ancestor_map(bone_labels: list[str], bone_parents: list[int]) -> list[int]:
    """For each Anny bone, the index in FIT_JOINTS of its nearest fitting ancestor (itself if
    it is one)."""
    fit_of_bone = {bone: j for j, (_, bone) in enumerate(FIT_JOINTS)}
    result = []
    for b in range(len(bone_labels)):
        a = b
        while bone_labels[a] not in fit_of_bone:
            a = bone_parents[a]
        result.append(fit_of_bone[bone_labels[a]])
    return result


class AnnyBody(BodyModel):
    """Anny as a :class:`BodyModel` (the embedded default)."""

    def __init__(
        self,
        local_changes: Literal["none", "all"] = "none",
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        if local_changes not in ("none", "all"):
            raise BodyModelError(f"local_changes must be 'none' or 'all', got {local_changes!r}")
        import anny  # deferred: importing anny loads warp

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = anny.Anny(local_changes=local_changes, skinning_method="lbs")
        model = model.to(dtype)
        self.anny = model
        self.identity = f"anny-{_anny_version()}:local_changes={local_changes}"
        self.joint_names = tuple(name for name, _ in FIT_JOINTS)
        bone_labels: list[str] = list(model.bone_labels)
        bone_parents: list[int] = [int(p) for p in model.bone_parents]
        self.fit_bone_ids = [bone_labels.index(bone) for _, bone in FIT_JOINTS]
        ancestor = _fit_ancestor_map(bone_labels, bone_parents)
        self.parents = tuple(
            -1 if j == 0 else ancestor[bone_parents[self.fit_bone_ids[j]]]
            for j in range(len(FIT_JOINTS))
        )
        self.local_change_names = tuple(model.local_change_labels)
        self.shape_names = PHENOTYPES + self.local_change_names
        self._num_facial = len(model.facial_action_labels)

        C = torch.as_tensor(ANNY_TO_CANONICAL, dtype=dtype)
        self.register_buffer("to_canonical", C, persistent=False)

        # skinning weights collapsed onto the fitting skeleton
        dense = torch.zeros(model.template_vertices.shape[0], len(bone_labels), dtype=dtype)
        dense.scatter_add_(1, model.vertex_bone_indices.long(), model.vertex_bone_weights)
        collapse = torch.zeros(len(bone_labels), len(FIT_JOINTS), dtype=dtype)
        collapse[torch.arange(len(bone_labels)), torch.tensor(ancestor)] = 1.0
        weights = dense @ collapse
        weights = weights / weights.sum(dim=1, keepdim=True)
        self.register_buffer("skin_weights", weights, persistent=False)
        self.register_buffer("faces", model.faces.long().clone(), persistent=False)
        uv = model.texture_coordinates.clone()
        uv[:, 1] = 1.0 - uv[:, 1]  # Anny: origin bottom-left → glTF: top-left, v down
        self.register_buffer("uv", uv, persistent=False)
        self.register_buffer(
            "face_uv", model.face_texture_coordinate_indices.long().clone(), persistent=False
        )

        with torch.no_grad():
            rest_vertices, _ = self.rest_shape(self.default_shape(1))
        rest = rest_vertices[0].double().numpy()
        parts = [_region_of_bone(bone_labels[b]) for b in dense.argmax(dim=1).tolist()]
        self.register_buffer(
            "regions", torch.as_tensor(labels.regions_from_parts(rest, parts)), persistent=False
        )
        mirror, self.mirror_error = labels.mirror_pairs(rest)
        self.register_buffer("mirror", torch.as_tensor(mirror, dtype=torch.long), persistent=False)
        kw, valid = self._keypoint_regressor(model, rest)
        self.register_buffer("keypoint_weights", kw.to(dtype), persistent=False)
        self.register_buffer("keypoint_valid", valid, persistent=False)

    # -- shape ------------------------------------------------------------------------------
    def blendshape_coefficients(self, shape: Tensor) -> Tensor:
        """(B, S) our shape parameters → (B, K) Anny blend-shape coefficients."""
        phenotypes = shape[:, : len(PHENOTYPES)] + 0.5
        local = shape[:, len(PHENOTYPES) :]
        facial = shape.new_zeros(shape.shape[0], self._num_facial)
        return self.anny._get_phenotype_blendshape_coefficients(phenotypes, local, facial)

    def rest_shape(self, shape: Tensor) -> tuple[Tensor, Tensor]:
        """shape (B, S) → rest vertices (B, V, 3), rest joints (B, J, 3); canonical frame."""
        from anny.skinning.skinning import apply_linear_blendshape

        coeffs = self.blendshape_coefficients(shape)
        vertices = self.anny.get_rest_vertices(coeffs)
        heads = apply_linear_blendshape(
            self.anny.template_bone_heads[self.fit_bone_ids],
            self.anny.bone_heads_blendshapes[:, self.fit_bone_ids],
            coeffs,
        )
        C = self.to_canonical
        return vertices @ C.T, heads @ C.T

    # -- derived labels ------------------------------------------------------------------------
    def _keypoint_regressor(
        self, model: torch.nn.Module, rest: np.ndarray
    ) -> tuple[Tensor, Tensor]:
        """(33, V) regression weights onto mediapipe's landmarks and their (33,) validity.

        Landmarks Anny's COCO regressor provides are taken from it; the others (eye corners,
        mouth corners, finger knuckles) are placed from the skeleton and the face geometry and
        regressed from their nearest surface vertices (:func:`_surface_regressor`)."""
        from anny.keypoints import KeypointsRegressor

        coco = KeypointsRegressor.coco(model)
        weights = coco.regression_weights.detach().double().numpy()
        coco_of = {label: weights[i] for i, label in enumerate(coco.labels)}
        out = np.zeros((len(MEDIAPIPE_LANDMARKS), rest.shape[0]))
        valid = np.zeros(len(MEDIAPIPE_LANDMARKS), dtype=bool)
        same = {name: name for name in MEDIAPIPE_LANDMARKS if name in coco_of}
        same.update({"left_foot_index": "left_big_toe", "right_foot_index": "right_big_toe"})
        for name, label in same.items():
            out[MEDIAPIPE_LANDMARKS.index(name)] = coco_of[label]
            valid[MEDIAPIPE_LANDMARKS.index(name)] = True

        def point(name: str) -> np.ndarray:
            return np.asarray(out[MEDIAPIPE_LANDMARKS.index(name)] @ rest)

        def front_surface(p: np.ndarray) -> np.ndarray:
            # the most forward vertex near p (within 1.5 cm in x and y): a landmark on the skin
            near = (np.abs(rest[:, 0] - p[0]) < 0.015) & (np.abs(rest[:, 1] - p[1]) < 0.015)
            if not near.any():
                return p
            cand = rest[near]
            q = cand[np.argmax(cand[:, 2])]
            return np.array([p[0], p[1], q[2]])

        extra: dict[str, np.ndarray] = {}
        for side, other in (("left", "right"), ("right", "left")):
            eye, eye_o = point(f"{side}_eye"), point(f"{other}_eye")
            extra[f"{side}_eye_inner"] = front_surface(eye + 0.22 * (eye_o - eye))
            extra[f"{side}_eye_outer"] = front_surface(eye - 0.22 * (eye_o - eye))
        nose = point("nose")
        eyes = 0.5 * (point("left_eye") + point("right_eye"))
        half_width = 0.42 * abs(point("left_eye")[0] - point("right_eye")[0])
        mouth_y = nose[1] - 0.9 * (eyes[1] - nose[1])
        left_sign = np.sign(point("left_eye")[0] - eyes[0])
        for side, sign in (("left", left_sign), ("right", -left_sign)):
            extra[f"mouth_{side}"] = front_surface(
                np.array([nose[0] + sign * half_width, mouth_y, nose[2]])
            )
        rest_heads, bone_names = self._rest_bone_heads()
        for side, s in (("left", "L"), ("right", "R")):
            extra[f"{side}_pinky"] = rest_heads[bone_names.index(f"finger5-1.{s}")]
            extra[f"{side}_index"] = rest_heads[bone_names.index(f"finger2-1.{s}")]
            extra[f"{side}_thumb"] = rest_heads[bone_names.index(f"finger1-3.{s}")]
        for name, target in extra.items():
            k = MEDIAPIPE_LANDMARKS.index(name)
            out[k] = labels.surface_regressor(rest, target)
            valid[k] = True
        return torch.as_tensor(out), torch.as_tensor(valid)

    def _rest_bone_heads(self) -> tuple[np.ndarray, list[str]]:
        """All Anny bone heads of the average body, canonical frame: (104, 3), labels."""
        from anny.skinning.skinning import apply_linear_blendshape

        with torch.no_grad():
            coeffs = self.blendshape_coefficients(self.default_shape(1))
            heads = apply_linear_blendshape(
                self.anny.template_bone_heads, self.anny.bone_heads_blendshapes, coeffs
            )[0]
        return (heads @ self.to_canonical.T).double().numpy(), list(self.anny.bone_labels)
