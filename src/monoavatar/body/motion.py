"""Procedural pose sequences in the fitting skeleton's axis-angle parameters (radians).

Canonical frame: Y up, the body faces +Z, its left is +X. A rotation about +X by a negative
angle swings a hanging limb forward; about +Z by a positive angle raises the left arm sideways.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from monoavatar.body.model import BodyModel


def _set(pose: np.ndarray, body: BodyModel, joint: str, axis: int,
         angle: np.ndarray | float) -> None:
    pose[:, body.joint_index(joint), axis] += angle


def turnaround(body: BodyModel, frames: int, rng: np.random.Generator, turns: float = 1.0,
               progress: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """A person in a rough A-pose turning ``turns`` times about the vertical axis
    (People-Snapshot-like, Sec. B.4.2), with small natural pose variation. ``progress`` (N,)
    non-decreasing in [0, 1): how far through the turn each frame is (None: evenly, frame i
    at i / N; :func:`uneven_progress` for a varying speed). Returns (N, J, 3)."""
    t = np.arange(frames) / max(frames, 1)
    turned = t if progress is None else np.asarray(progress, dtype=np.float64)
    pose = np.zeros((frames, body.num_joints, 3))
    start = rng.uniform(-0.2, 0.2)
    _set(pose, body, "pelvis", 1, start + 2 * np.pi * turns * turned)
    for j in range(1, body.num_joints):  # slow wobble of a few degrees
        amp = rng.uniform(0.01, 0.05, 3)
        phase = rng.uniform(0, 2 * np.pi, 3)
        freq = rng.uniform(0.5, 2.0, 3)
        pose[:, j] += amp * np.sin(2 * np.pi * freq * t[:, None] + phase)
    abduct = rng.uniform(-0.1, 0.25)  # arms a little further from or closer to the body
    _set(pose, body, "shoulder_l", 2, abduct + 0.05 * np.sin(2 * np.pi * t))
    _set(pose, body, "shoulder_r", 2, -abduct - 0.05 * np.sin(2 * np.pi * t))
    return pose


def uneven_progress(frames: int, wobble: float, rng: np.random.Generator) -> np.ndarray:
    """(N,) how far through a turn frame i is when the turning speed varies: i / N warped by
    ``p(t) = t + Σ_k a_k sin(2π k t + φ_k) / (2π k) − (the same at 0)`` over k = 1, 2 with
    ``|a_1| + |a_2| = wobble`` (< 1), so the speed ``1 + Σ a_k cos(…)`` stays within
    ``1 ± wobble`` of the mean and the progress never runs backwards."""
    if not 0.0 <= wobble < 1.0:
        raise ValueError(f"wobble must lie in [0, 1), got {wobble}")
    t = np.arange(frames) / max(frames, 1)
    share = rng.uniform(0.3, 0.7)
    amplitude = wobble * np.array([share, 1.0 - share]) * rng.choice([-1.0, 1.0], 2)
    phase = rng.uniform(0, 2 * np.pi, 2)
    out = t.copy()
    for k, (a, phi) in enumerate(zip(amplitude, phase, strict=True), start=1):
        out += a * (np.sin(2 * np.pi * k * t + phi) - np.sin(phi)) / (2 * np.pi * k)
    return out


def free_motion(body: BodyModel, frames: int, rng: np.random.Generator, fps: float = 30.0):
    """Walking in place, then waving the right arm, then jogging in place, with a slowly
    varying heading. Returns poses (N, J, 3) and translations (N, 3) in metres."""
    pose = np.zeros((frames, body.num_joints, 3))
    transl = np.zeros((frames, 3))
    time = np.arange(frames) / fps
    third = np.arange(frames) * 3 // max(frames, 1)
    _set(pose, body, "pelvis", 1, 0.5 * np.sin(2 * np.pi * time / 8.0) + rng.uniform(-0.3, 0.3))
    for phase_id, (freq, hip, knee, arm, bounce) in enumerate(
        [(0.9, 0.35, 0.5, 0.3, 0.01), (0.0, 0.0, 0.0, 0.0, 0.0), (1.6, 0.6, 1.1, 0.6, 0.04)]
    ):
        sel = third == phase_id
        s = np.sin(2 * np.pi * freq * time[sel])
        c = np.clip(np.sin(2 * np.pi * freq * time[sel]), 0, None)
        c2 = np.clip(-np.sin(2 * np.pi * freq * time[sel]), 0, None)
        pose[sel, body.joint_index("hip_l"), 0] += -hip * c
        pose[sel, body.joint_index("knee_l"), 0] += knee * c
        pose[sel, body.joint_index("hip_r"), 0] += -hip * c2
        pose[sel, body.joint_index("knee_r"), 0] += knee * c2
        pose[sel, body.joint_index("shoulder_l"), 0] += arm * s
        pose[sel, body.joint_index("shoulder_r"), 0] += -arm * s
        pose[sel, body.joint_index("elbow_l"), 0] += -0.3 - arm * c
        pose[sel, body.joint_index("elbow_r"), 0] += -0.3 - arm * c2
        transl[sel, 1] += bounce * np.abs(s)
        if phase_id == 1:  # wave: right arm up, forearm swinging
            wave = np.sin(2 * np.pi * 1.5 * time[sel])
            pose[sel, body.joint_index("shoulder_r"), 2] += -1.6
            pose[sel, body.joint_index("elbow_r"), 2] += -0.9 + 0.4 * wave
    return pose, transl


#: Ranges (joint, axis, low, high) in radians of :func:`limb_motion`'s angles; axes as in the
#: module's docstring (left arm raised sideways: +Z on shoulder_l; knee flexion +X; elbow −X).
LIMB_RANGES: tuple[tuple[str, int, float, float], ...] = (
    ("spine1", 0, -0.2, 0.5), ("spine1", 1, -0.3, 0.3), ("spine1", 2, -0.2, 0.2),
    ("spine2", 0, -0.1, 0.3), ("spine2", 1, -0.3, 0.3), ("spine3", 1, -0.2, 0.2),
    ("neck", 0, -0.3, 0.4), ("neck", 1, -0.5, 0.5), ("head", 0, -0.3, 0.3),
    ("shoulder_l", 0, -1.6, 0.6), ("shoulder_l", 1, -0.6, 0.6), ("shoulder_l", 2, -1.2, 1.0),
    ("shoulder_r", 0, -1.6, 0.6), ("shoulder_r", 1, -0.6, 0.6), ("shoulder_r", 2, -1.0, 1.2),
    ("elbow_l", 0, -2.3, 0.0), ("elbow_r", 0, -2.3, 0.0),
    ("wrist_l", 0, -0.5, 0.5), ("wrist_r", 0, -0.5, 0.5),
    ("hip_l", 0, -1.4, 0.4), ("hip_l", 2, -0.15, 0.6), ("hip_l", 1, -0.4, 0.4),
    ("hip_r", 0, -1.4, 0.4), ("hip_r", 2, -0.6, 0.15), ("hip_r", 1, -0.4, 0.4),
    ("knee_l", 0, 0.0, 2.2), ("knee_r", 0, 0.0, 2.2),
    ("ankle_l", 0, -0.4, 0.4), ("ankle_r", 0, -0.4, 0.4),
)  # fmt: skip


def limb_motion(body: BodyModel, frames: int, rng: np.random.Generator, fps: float = 30.0
                ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Unstructured motion for learning: each angle of :data:`LIMB_RANGES` a random centre plus
    one or two sinusoids of 0.2–2.2 Hz, clipped to its range, left and right independent; the
    heading about +Y drifts from a random start by up to ±0.8 rad, the body leans a little;
    the root moves on a slow random path (up to about 1 m) with a small vertical bounce.

    Returns poses (N, J, 3) axis-angle radians and translations (N, 3) metres.
    """
    time = np.arange(frames) / fps
    pose = np.zeros((frames, body.num_joints, 3))
    for joint, axis, lo, hi in LIMB_RANGES:
        centre = rng.uniform(lo, hi)
        angle = np.full(frames, centre)
        for _ in range(int(rng.integers(1, 3))):
            amp = rng.uniform(0.0, 0.5) * (hi - lo)
            angle += amp * np.sin(2 * np.pi * rng.uniform(0.2, 2.2) * time + rng.uniform(0, 7))
        _set(pose, body, joint, axis, np.clip(angle, lo, hi))
    heading = rng.uniform(-np.pi, np.pi) + rng.uniform(-0.8, 0.8) * np.sin(
        2 * np.pi * rng.uniform(0.02, 0.2) * time + rng.uniform(0, 7))
    lean = rng.uniform(-0.15, 0.15, 2)
    root = Rotation.from_rotvec(np.stack([np.zeros(frames), heading, np.zeros(frames)], -1))
    pose[:, 0] = (root * Rotation.from_rotvec([lean[0], 0.0, lean[1]])).as_rotvec()
    transl = np.zeros((frames, 3))
    for axis in (0, 2):
        transl[:, axis] = rng.uniform(-0.5, 0.5) * np.sin(
            2 * np.pi * rng.uniform(0.02, 0.15) * time + rng.uniform(0, 7))
    transl[:, 1] = rng.uniform(0.0, 0.04) * np.abs(np.sin(2 * np.pi * rng.uniform(0.5, 2) * time))
    return pose, transl


def standing_pose(body: BodyModel, rng: np.random.Generator) -> np.ndarray:
    """A varied standing pose roughly facing the camera (±35°), for single photos. (J, 3)."""
    pose = 0.06 * rng.standard_normal((body.num_joints, 3))
    pose[body.joint_index("pelvis"), 1] = rng.uniform(-0.6, 0.6)
    for s, sign in (("l", 1.0), ("r", -1.0)):
        pose[body.joint_index(f"shoulder_{s}"), 2] += sign * rng.uniform(-0.2, 0.9)
        pose[body.joint_index(f"shoulder_{s}"), 0] += rng.uniform(-0.5, 0.3)
        pose[body.joint_index(f"elbow_{s}"), 0] += -rng.uniform(0.0, 1.2)
        pose[body.joint_index(f"hip_{s}"), 2] += sign * rng.uniform(-0.05, 0.15)
    leg = rng.choice(["l", "r"])
    pose[body.joint_index(f"hip_{leg}"), 0] += -rng.uniform(0.0, 0.3)
    pose[body.joint_index(f"knee_{leg}"), 0] += rng.uniform(0.0, 0.4)
    return pose


#: Gait styles of :func:`gait`: (cycle frequency Hz, hip swing rad, knee flexion rad, arm swing
#: rad, elbow bend rad, vertical bounce m, natural speed m/s).
GAITS: dict[str, tuple[float, float, float, float, float, float, float]] = {
    "walk": (0.9, 0.40, 0.70, 0.30, 0.35, 0.015, 1.1),
    "jog": (1.4, 0.60, 1.30, 0.55, 1.30, 0.040, 2.2),
}


def gait(body: BodyModel, frames: int, rng: np.random.Generator, fps: float = 30.0,
         style: str = "walk", path_length: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Walking or jogging along a straight path at an oblique angle to the camera (which looks
    along −Z at the origin from +Z).

    The heading (the direction the body faces and travels, about +Y) is 35–65° from the
    camera's axis, towards or away from the camera, left or right, drawn from ``rng``; the
    path, centred at the origin, is at most ``path_length`` metres long (the speed is the
    style's natural one or slower, so that it stays in view); amplitudes vary by ±15 %.

    Returns:
        poses (N, J, 3) axis-angle radians and translations (N, 3) metres.
    """
    if style not in GAITS:
        raise ValueError(f"gait style must be one of {sorted(GAITS)}, got {style!r}")
    freq, hip, knee, arm, elbow, bounce, speed = GAITS[style]
    jitter = rng.uniform(0.85, 1.15, 5)
    hip, knee, arm, bounce = hip * jitter[0], knee * jitter[1], arm * jitter[2], bounce * jitter[3]
    freq *= jitter[4]
    time = np.arange(frames) / fps
    phi = 2 * np.pi * freq * time + rng.uniform(0, 2 * np.pi)
    s = np.sin(phi)
    pose = np.zeros((frames, body.num_joints, 3))
    _set(pose, body, "hip_l", 0, -hip * s)
    _set(pose, body, "hip_r", 0, hip * s)
    _set(pose, body, "knee_l", 0, 0.1 + knee * np.clip(np.sin(phi + 0.6), 0.0, None))
    _set(pose, body, "knee_r", 0, 0.1 + knee * np.clip(-np.sin(phi + 0.6), 0.0, None))
    _set(pose, body, "ankle_l", 0, -0.15 * np.clip(np.sin(phi + 0.6), 0.0, None))
    _set(pose, body, "ankle_r", 0, -0.15 * np.clip(-np.sin(phi + 0.6), 0.0, None))
    _set(pose, body, "shoulder_l", 2, -0.6 + rng.uniform(-0.1, 0.1))  # arms down at the sides
    _set(pose, body, "shoulder_r", 2, 0.6 + rng.uniform(-0.1, 0.1))
    _set(pose, body, "shoulder_l", 0, arm * s)
    _set(pose, body, "shoulder_r", 0, -arm * s)
    _set(pose, body, "elbow_l", 0, -elbow - 0.2 * arm * np.clip(-s, 0.0, None))
    _set(pose, body, "elbow_r", 0, -elbow - 0.2 * arm * np.clip(s, 0.0, None))
    _set(pose, body, "spine2", 1, -0.08 * s)
    _set(pose, body, "spine1", 0, 0.1 if style == "jog" else 0.03)  # leaning into the run
    heading = np.deg2rad(rng.uniform(35.0, 65.0)) * rng.choice([-1.0, 1.0])
    if rng.random() < 0.5:
        heading += np.pi  # walking away from the camera
    sway = np.zeros((frames, 3))
    sway[:, 1] = 0.08 * s
    sway[:, 2] = 0.03 * np.cos(phi)
    root = Rotation.from_rotvec([0.0, heading, 0.0]) * Rotation.from_rotvec(sway)
    pose[:, 0] = root.as_rotvec()
    direction = np.array([np.sin(heading), 0.0, np.cos(heading)])
    duration = frames / fps
    length = min(path_length, speed * duration)
    travelled = length * (time / max(duration, 1e-9) - 0.5)
    translations = travelled[:, None] * direction
    translations[:, 1] = bounce * np.abs(np.cos(phi))
    return pose, translations


def upright_rotation(up: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking the unit direction ``up`` (3,) to +Y (glTF's up);
    a half turn about +X when ``up`` is -Y (the world of a camera, y down)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    y = np.array([0.0, 1.0, 0.0])
    axis = np.cross(u, y)
    sin, cos = float(np.linalg.norm(axis)), float(u @ y)
    if sin < 1e-9:
        return np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])
    angle = np.arctan2(sin, cos)
    return Rotation.from_rotvec(axis / sin * angle).as_matrix()


def turn_upright(poses: np.ndarray, translations: np.ndarray, up: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A motion (poses (N, J, 3) axis-angle, translations (N, 3) metres) in a world whose up
    is ``up`` (3,), turned into a Y-up world by :func:`upright_rotation`: the root rotation and
    the translations turn, the other joints are local and stay."""
    turn = upright_rotation(up)
    if np.allclose(turn, np.eye(3)):
        return poses, translations
    poses = np.array(poses, dtype=np.float64)
    root = Rotation.from_matrix(turn) * Rotation.from_rotvec(poses[:, 0])
    poses[:, 0] = root.as_rotvec()
    return poses, np.asarray(translations, dtype=np.float64) @ turn.T
