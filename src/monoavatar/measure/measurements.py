"""Tailor's measurements of a body mesh in its rest pose, from the mesh and its skeleton.

Every measurement is taken in the *body frame* of the skeleton, so it does not depend on how the
mesh is oriented: origin at the pelvis joint, up along pelvis → neck, left along right hip → left
hip (made orthogonal to up), forward = left × up. Heights below are along up; ``T`` is the torso
length (pelvis → neck, along up). A *girth* is the length of the convex hull of a plane section
(a tape drawn around it) restricted to the body parts named; a band of heights is sampled at
``MeasureSettings.samples`` slices and the largest or smallest girth kept. Parts come from the
body model's skinning (:func:`vertex_parts`), so an arm hanging beside the torso is not wrapped
into the chest.

=============== ============================================================================
height          top of the mesh − bottom of the mesh
neck            girth ⟂ neck → head, half-way along it (neck and head)
chest           largest torso girth, horizontal, heights spine3 + T·[−0.15, +0.05]
waist           smallest torso girth, horizontal, heights [spine1 + 0.05 T, spine2 + 0.1 T]
hip             largest girth of torso and both legs, horizontal, heights
                [hip joints − 0.1·thigh bone, spine1] (above the crotch: lower, the tape
                would span the parted legs of the A-pose)
upper_arm       girth ⟂ shoulder → elbow, half-way (the arm alone; mean of both sides)
thigh           largest girth ⟂ hip → knee over 25–50 % of the bone (one leg; mean of both)
calf            largest girth ⟂ knee → ankle over 20–50 % of the bone (one leg; mean of both)
shoulder_width  straight distance between the two shoulder tops: the highest surface point of
                torso or arm on the vertical line through each shoulder joint
arm_length      shoulder top → elbow joint → wrist joint (mean of both sides)
inseam          crotch above the soles: the lowest surface point of torso or legs on the
                vertical line half-way between the hip joints, minus the bottom of the mesh
=============== ============================================================================
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from monoavatar.measure.slicing import Section, girth, plane_section, vertical_hits

__all__ = [
    "MEASUREMENTS",
    "PARTS",
    "MeasureSettings",
    "Measurement",
    "Slicer",
    "body_frame",
    "body_under_clothes",
    "face_parts",
    "measure_mesh",
    "transfer_parts",
    "vertex_parts",
]

MEASUREMENTS: tuple[str, ...] = ("height", "chest", "waist", "hip", "neck", "upper_arm", "thigh",
                                 "calf", "shoulder_width", "arm_length", "inseam")  # fmt: skip
"""The measurements, in the order they are reported."""

PARTS: tuple[str, ...] = ("torso", "neck", "head", "arm_l", "arm_r", "leg_l", "leg_r")
"""Body parts, by index; a vertex's part is that of its most weighted skinning joint."""

_PART_OF_JOINT = {
    "pelvis": "torso", "spine1": "torso", "spine2": "torso", "spine3": "torso",
    "collar_l": "torso", "collar_r": "torso", "neck": "neck", "head": "head",
    "shoulder_l": "arm_l", "elbow_l": "arm_l", "wrist_l": "arm_l",
    "shoulder_r": "arm_r", "elbow_r": "arm_r", "wrist_r": "arm_r",
    "hip_l": "leg_l", "knee_l": "leg_l", "ankle_l": "leg_l",
    "hip_r": "leg_r", "knee_r": "leg_r", "ankle_r": "leg_r",
}  # fmt: skip


@dataclass(frozen=True)
class MeasureSettings:
    """Where the measurements are taken (fractions as in the module docstring)."""

    samples: int = 15
    chest_band: tuple[float, float] = (-0.15, 0.05)
    waist_band: tuple[float, float] = (0.05, 0.10)
    hip_band: float = 0.10
    thigh_band: tuple[float, float] = (0.25, 0.50)
    calf_band: tuple[float, float] = (0.20, 0.50)


@dataclass(frozen=True)
class Slicer:
    """The geometry measurements are made of: ``section(vertices, faces, origin, normal)`` →
    :class:`~monoavatar.measure.slicing.Section` and ``hits(vertices, faces, x, z)`` → sorted
    heights where the vertical line (x, ·, z) crosses the mesh (Y up). The benchmark passes
    independent ones (trimesh's) to measure the ground truth."""

    section: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], Section] = plane_section
    hits: Callable[[np.ndarray, np.ndarray, float, float], np.ndarray] = vertical_hits


@dataclass
class Measurement:
    """One measurement.

    Attributes:
        value: metres (NaN when it cannot be taken, e.g. no crotch between merged legs).
        kind: ``"girth"`` or ``"length"``.
        drawing: polylines (P, 3) in the measured mesh's frame that show it (a girth's hull,
            closed; a length's end points).
    """

    value: float
    kind: str
    drawing: list[np.ndarray] = field(default_factory=list)


def body_under_clothes(rest: np.ndarray, normals: np.ndarray,
                       offsets: np.ndarray) -> np.ndarray:  # fmt: skip
    """(V, 3) the body under the clothes of an SMPL+D avatar: the body model's rest vertices
    (V, 3) with the offsets (V, 3) that point into the body (against the unit ``normals``
    (V, 3)) kept, and those that point out (clothing, hair, or body the shape did not explain)
    dropped, so the body never lies outside the clothed surface."""
    inward = np.einsum("vi,vi->v", offsets, normals) < 0
    return rest + np.where(inward[:, None], offsets, 0.0)


def vertex_parts(skin_weights: np.ndarray, joint_names: Sequence[str]) -> np.ndarray:
    """(V,) part index (into :data:`PARTS`) of each vertex, from (V, J) skinning weights."""
    missing = [n for n in _PART_OF_JOINT if n not in joint_names]
    if missing:
        raise ValueError(f"the skeleton lacks the joints {missing} that measurements need")
    part_of_joint = np.array([PARTS.index(_PART_OF_JOINT.get(n, "torso")) for n in joint_names])
    return part_of_joint[np.argmax(skin_weights, axis=1)]


def transfer_parts(source: np.ndarray, parts: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(T,) parts of ``target`` (T, 3) vertices: those of their nearest ``source`` (V, 3)
    vertex (a clothed or subdivided mesh labelled from the body model under it)."""
    _, idx = cKDTree(source).query(target)
    return parts[idx]


def face_parts(faces: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """(F,) part of each face: the part of at least two of its vertices, else its first's."""
    p = parts[faces]
    return np.where(p[:, 1] == p[:, 2], p[:, 1], p[:, 0])


def body_frame(joints: np.ndarray, joint_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """The body frame of a skeleton: rotation (3, 3), rows left, up, forward, and origin (3,)
    (the pelvis joint); a point p has body coordinates ``(p - origin) @ R.T``."""
    j = {n: joints[i] for i, n in enumerate(joint_names)}
    up = j["neck"] - j["pelvis"]
    up /= np.linalg.norm(up)
    left = j["hip_l"] - j["hip_r"]
    left = left - (left @ up) * up
    left /= np.linalg.norm(left)
    return np.stack([left, up, np.cross(left, up)]), j["pelvis"].copy()


def measure_mesh(vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray,
                 joints: np.ndarray, joint_names: Sequence[str],
                 settings: MeasureSettings | None = None,
                 slicer: Slicer | None = None) -> dict[str, Measurement]:  # fmt: skip
    """All :data:`MEASUREMENTS` of a rest-pose mesh.

    Args:
        vertices: (V, 3) metres; faces: (F, 3); parts: (V,) part index of each vertex
            (:func:`vertex_parts`, :func:`transfer_parts`).
        joints: (J, 3) the skeleton's joints in the mesh's frame, metres, named by
            ``joint_names`` (pelvis, spine1..3, neck, head, shoulder/elbow/wrist, hip/knee/ankle
            with ``_l``/``_r``).
        slicer: the plane sections and vertical hits (default: this package's).
    Returns:
        name → :class:`Measurement`, in :data:`MEASUREMENTS` order.
    """
    s = settings or MeasureSettings()
    geometry = slicer or Slicer()
    R, origin = body_frame(np.asarray(joints, float), joint_names)
    v = (np.asarray(vertices, float) - origin) @ R.T
    jb = (np.asarray(joints, float) - origin) @ R.T
    j = {n: jb[i] for i, n in enumerate(joint_names)}
    fp = face_parts(np.asarray(faces), np.asarray(parts))
    up = np.array([0.0, 1.0, 0.0])

    def back(points: np.ndarray) -> np.ndarray:
        return points @ R + origin

    def girth_at(point: np.ndarray, normal: np.ndarray, names: Sequence[str]) -> tuple[float,
                                                                                       np.ndarray]:
        section = geometry.section(v, faces, point, normal).keep(np.isin(fp, [PARTS.index(n)
                                                                           for n in names]))
        return girth(section)

    def best(found: list[tuple[float, np.ndarray]], pick: str = "max") -> Measurement:
        """The largest (or smallest) of the girths ``found``, drawn; NaN when none is."""
        lengths = np.array([g for g, _ in found])
        if not (lengths > 0).any():
            return Measurement(float("nan"), "girth")
        masked = np.where(lengths > 0, lengths, -np.inf if pick == "max" else np.inf)
        k = int(np.argmax(masked) if pick == "max" else np.argmin(masked))
        return Measurement(float(lengths[k]), "girth", [back(_closed(found[k][1]))])

    def horizontal(heights: np.ndarray, names: Sequence[str], pick: str) -> Measurement:
        return best([girth_at(np.array([0.0, h, 0.0]), up, names) for h in heights], pick)

    def along(a: str, b: str, band: tuple[float, float], names: Sequence[str]) -> Measurement:
        axis = j[b] - j[a]
        count = s.samples if band[0] != band[1] else 1
        return best([girth_at(j[a] + f * axis, axis, names)
                     for f in np.linspace(band[0], band[1], count)])  # fmt: skip

    def both(make: Callable[[str], Measurement]) -> Measurement:
        sides = [make(side) for side in ("l", "r")]
        value = float(np.nanmean([m.value for m in sides])) if any(
            np.isfinite(m.value) for m in sides) else float("nan")
        return Measurement(value, sides[0].kind, [d for m in sides for d in m.drawing])

    torso_length = float(j["neck"][1])  # the pelvis is the origin
    hip_y = 0.5 * (j["hip_l"][1] + j["hip_r"][1])
    thigh_bone = 0.5 * (np.linalg.norm(j["knee_l"] - j["hip_l"])
                        + np.linalg.norm(j["knee_r"] - j["hip_r"]))  # fmt: skip
    floor, top = float(v[:, 1].min()), float(v[:, 1].max())
    beside, behind = float(v[:, 0].min()) - 0.05, float(v[:, 2].min()) - 0.05
    n = s.samples
    limbs = [PARTS.index(p) for p in ("torso", "arm_l", "arm_r", "leg_l", "leg_r")]
    limb_faces = faces[np.isin(fp, limbs)]
    trunk_faces = faces[np.isin(fp, [PARTS.index(p) for p in ("torso", "leg_l", "leg_r")])]

    def shoulder_top(side: str) -> np.ndarray:
        x, _, z = j[f"shoulder_{side}"]
        hits = geometry.hits(v, limb_faces, x, z)
        hits = hits[hits > j[f"shoulder_{side}"][1]]
        return np.array([x, hits.max() if len(hits) else np.nan, z])

    tops = {side: shoulder_top(side) for side in ("l", "r")}
    mid_hip = 0.5 * (j["hip_l"] + j["hip_r"])
    crotch_hits = geometry.hits(v, trunk_faces, mid_hip[0], mid_hip[2])
    crotch_hits = crotch_hits[crotch_hits < hip_y]
    crotch = float(crotch_hits.min()) if len(crotch_hits) else float("nan")

    def arm(side: str) -> Measurement:
        a, e, w = tops[side], j[f"elbow_{side}"], j[f"wrist_{side}"]
        value = float(np.linalg.norm(a - e) + np.linalg.norm(e - w))
        return Measurement(value, "length", [back(np.stack([a, e, w]))])

    neck_axis = j["head"] - j["neck"]
    result = {
        "height": Measurement(top - floor, "length",  # drawn beside the body, to its right
                              [back(np.array([[beside, floor, behind], [beside, top, behind]]))]),
        "chest": horizontal(j["spine3"][1] + torso_length * np.linspace(*s.chest_band, n),
                            ["torso"], "max"),
        "waist": horizontal(np.linspace(j["spine1"][1] + s.waist_band[0] * torso_length,
                                        j["spine2"][1] + s.waist_band[1] * torso_length, n),
                            ["torso"], "min"),
        "hip": horizontal(np.linspace(hip_y - s.hip_band * thigh_bone, j["spine1"][1], n),
                          ["torso", "leg_l", "leg_r"], "max"),
        "neck": best([girth_at(j["neck"] + 0.5 * neck_axis, neck_axis, ["neck", "head"])]),
        "upper_arm": both(lambda d: along(f"shoulder_{d}", f"elbow_{d}", (0.5, 0.5),
                                          [f"arm_{d}"])),
        "thigh": both(lambda d: along(f"hip_{d}", f"knee_{d}", s.thigh_band, [f"leg_{d}"])),
        "calf": both(lambda d: along(f"knee_{d}", f"ankle_{d}", s.calf_band, [f"leg_{d}"])),
        "shoulder_width": Measurement(float(np.linalg.norm(tops["l"] - tops["r"])), "length",
                                      [back(np.stack([tops["l"], tops["r"]]))]),
        "arm_length": both(arm),
        "inseam": Measurement(crotch - floor, "length",
                              [back(np.array([[mid_hip[0], crotch, mid_hip[2]],
                                              [mid_hip[0], floor, mid_hip[2]]]))]),
    }  # fmt: skip
    return {name: result[name] for name in MEASUREMENTS}


def _closed(corners: np.ndarray) -> np.ndarray:
    return np.vstack([corners, corners[:1]]) if len(corners) else corners
