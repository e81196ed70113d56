"""Body proportions of a rest-pose body, and the adult range each may take.

Suite v2's subjects carry strong local shape changes; drawn independently, those changes can
give a body proportions no adult has (a foot a fifth of the stature long, half as broad as
long). :func:`plausible` tells whether every proportion lies in :data:`ADULT_PROPORTIONS`.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from monoavatar.body import BodyModel

__all__ = ["ADULT_PROPORTIONS", "adult_proportion_ranges", "body_proportions", "measure_body",
           "plausible"]

#: Name → (low, high): each proportion's span over the corners of Anny's adult phenotype box
#: (:func:`adult_proportion_ranges`). Lengths are fractions of the stature (the rest pose's
#: height); ``foot_breadth`` is a fraction of the foot's length.
ADULT_PROPORTIONS: dict[str, tuple[float, float]] = {
    "foot_length": (0.133, 0.174),
    "foot_breadth": (0.371, 0.424),
    "hand_length": (0.100, 0.140),
    "arm_length": (0.264, 0.302),
    "leg_length": (0.395, 0.524),
    "head_height": (0.123, 0.186),
    "head_breadth": (0.090, 0.136),
    "shoulder_width": (0.168, 0.273),
}

def body_proportions(vertices: np.ndarray, joints: np.ndarray, part: np.ndarray,
                     joint_names: tuple[str, ...]) -> dict[str, float]:  # fmt: skip
    """Proportions of a body standing in the rest pose (+Y up, facing +Z), metres in.

    Args:
        vertices: (V, 3) rest-pose vertices.
        joints: (J, 3) rest-pose joints.
        part: (V,) each vertex's joint (the largest skin weight).
        joint_names: the J joint names; Anny's (``ankle_l``, ``wrist_l``, ``head``, …).

    Returns:
        Each of :data:`ADULT_PROPORTIONS`' names, for sided ones the left (``…/l``) and the
        right (``…/r``) value; empty for a skeleton without Anny's joint names.
    """
    index = {name: i for i, name in enumerate(joint_names)}
    needed = ("head", "ankle_l", "wrist_l", "shoulder_l", "elbow_l", "hip_l", "knee_l")
    if any(n not in index for n in needed) or any(n[:-1] + "r" not in index for n in needed[1:]):
        return {}
    stature = float(np.ptp(vertices[:, 1]))
    out: dict[str, float] = {}
    for side in ("l", "r"):
        j = {n: joints[index[f"{n}_{side}"]] for n in ("ankle", "wrist", "shoulder", "elbow",
                                                        "hip", "knee")}  # fmt: skip
        foot = vertices[part == index[f"ankle_{side}"]]
        length = float(np.ptp(foot[:, 2]))
        sole = foot[foot[:, 1] < j["ankle"][1] - 0.03]
        out[f"foot_length/{side}"] = length / stature
        out[f"foot_breadth/{side}"] = float(np.ptp(sole[:, 0])) / max(length, 1e-9)
        hand = vertices[part == index[f"wrist_{side}"]]
        reach = float(np.linalg.norm(hand - j["wrist"], axis=1).max())
        out[f"hand_length/{side}"] = reach / stature
        out[f"arm_length/{side}"] = float(np.linalg.norm(j["elbow"] - j["shoulder"])
                                          + np.linalg.norm(j["wrist"] - j["elbow"])) / stature
        out[f"leg_length/{side}"] = float(np.linalg.norm(j["knee"] - j["hip"])
                                          + np.linalg.norm(j["ankle"] - j["knee"])) / stature
    head = vertices[part == index["head"]]
    out["head_height"] = float(np.ptp(head[:, 1])) / stature
    out["head_breadth"] = float(np.ptp(head[:, 0])) / stature
    out["shoulder_width"] = float(np.linalg.norm(joints[index["shoulder_l"]]
                                                 - joints[index["shoulder_r"]])) / stature
    return out


def measure_body(body: BodyModel, shape: np.ndarray) -> tuple[float, dict[str, float]]:
    """The stature (metres: the rest pose's height, soles to the top of the head) and the
    :func:`body_proportions` of ``body`` with (S,) ``shape``, from one rest-pose evaluation."""
    with torch.no_grad():
        vertices, joints = body.rest_shape(torch.as_tensor(shape, dtype=body.dtype)[None])
    v = vertices[0].double().numpy()
    part = body.skin_weights.argmax(dim=1).numpy()
    return float(np.ptp(v[:, 1])), body_proportions(v, joints[0].double().numpy(), part,
                                                    tuple(body.joint_names))  # fmt: skip


def plausible(proportions: dict[str, float],
              ranges: dict[str, tuple[float, float]] | None = None) -> bool:  # fmt: skip
    """Whether every one of ``proportions`` (:func:`body_proportions`) lies in ``ranges``
    (default :data:`ADULT_PROPORTIONS`); True for none (a skeleton without Anny's names)."""
    ranges = ADULT_PROPORTIONS if ranges is None else ranges
    for key, value in proportions.items():
        low, high = ranges[key.split("/")[0]]
        if not low <= value <= high:
            return False
    return True


def adult_proportion_ranges(body: BodyModel) -> dict[str, tuple[float, float]]:
    """Each proportion's span over the corners of the adult phenotype box the wide subjects
    draw from (gender ±0.5, age −0.1 or 0.35, muscle, weight, height and proportions ±0.5; no
    local changes): :data:`ADULT_PROPORTIONS` for ``anny-local``."""
    values: dict[str, list[float]] = {}
    for corner in itertools.product((-0.5, 0.5), (-0.1, 0.35), *[(-0.5, 0.5)] * 4):
        shape = np.zeros(body.shape_dim)
        shape[:6] = corner
        for key, value in measure_body(body, shape)[1].items():
            values.setdefault(key.split("/")[0], []).append(value)
    return {key: (min(v), max(v)) for key, v in values.items()}
