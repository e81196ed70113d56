"""Meshes of known girth for the measurement tests: polygonal prisms (a cylinder or an
elliptic cylinder) along any axis, and a body assembled from them with its skeleton."""

from __future__ import annotations

import numpy as np

from monoavatar.measure import PARTS


def prism(start: np.ndarray, end: np.ndarray, a: float, b: float | None = None, n: int = 48,
          rings: int = 9, up: np.ndarray | None = None
          ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A closed prism from ``start`` to ``end`` (3,) whose cross-section is the n-gon inscribed
    in the ellipse of semi-axes ``a`` (along ``up`` made orthogonal to the axis, or any
    perpendicular) and ``b`` (default ``a``). Returns vertices (V, 3), faces (F, 3)."""
    b = a if b is None else b
    axis = end - start
    length = np.linalg.norm(axis)
    w = axis / length
    ref = up if up is not None else np.eye(3)[int(np.argmin(np.abs(w)))]
    u = ref - (ref @ w) * w
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    theta = 2 * np.pi * np.arange(n) / n
    ring = a * np.cos(theta)[:, None] * u + b * np.sin(theta)[:, None] * v
    verts = [start + t * axis + ring for t in np.linspace(0, 1, rings)]
    vertices = np.concatenate(verts + [start[None], end[None]])
    faces = []
    for r in range(rings - 1):
        for i in range(n):
            p, q = r * n + i, r * n + (i + 1) % n
            faces += [[p, q, q + n], [p, q + n, p + n]]
    bottom, top = rings * n, rings * n + 1
    for i in range(n):
        last = (rings - 1) * n
        faces += [[bottom, (i + 1) % n, i], [top, last + i, last + (i + 1) % n]]
    return vertices, np.array(faces)


def polygon_perimeter(a: float, b: float, n: int = 48) -> float:
    """Perimeter of the n-gon inscribed in the ellipse (a, b) at the prism's angles."""
    theta = 2 * np.pi * np.arange(n + 1) / n
    pts = np.stack([a * np.cos(theta), b * np.sin(theta)], 1)
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


JOINT_NAMES = ("pelvis", "spine1", "spine2", "spine3", "neck", "head", "collar_l", "shoulder_l",
               "elbow_l", "wrist_l", "collar_r", "shoulder_r", "elbow_r", "wrist_r", "hip_l",
               "knee_l", "ankle_l", "hip_r", "knee_r", "ankle_r")  # fmt: skip

TORSO = (0.15, 0.10)  # semi-axes, left-right and front-back
NECK, ARM, LEG = 0.05, 0.035, 0.04  # radii
FLOOR, CROTCH, TOP = -0.85, -0.05, 0.70


def primitive_body() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A body of prisms, Y up, facing +Z, left +X: an elliptic torso (y -0.05..0.55), a neck
    cylinder (to 0.70), arm cylinders at 45 degrees from the shoulders, leg cylinders from the
    hip joints to the floor (-0.85). Returns vertices, faces, parts (V,), joints (20, 3)."""
    d = np.array([np.sin(np.pi / 4), -np.cos(np.pi / 4), 0.0])
    j = {"pelvis": (0, 0, 0), "spine1": (0, 0.1, 0), "spine2": (0, 0.25, 0),
         "spine3": (0, 0.4, 0), "neck": (0, 0.55, 0), "head": (0, 0.65, 0)}
    for s, x in (("l", 1.0), ("r", -1.0)):
        m = np.array([x, 1.0, 1.0])
        j[f"collar_{s}"] = (0.02 * x, 0.5, 0)
        j[f"shoulder_{s}"] = tuple(np.array([0.18, 0.5, 0]) * m)
        j[f"elbow_{s}"] = tuple((np.array([0.18, 0.5, 0]) + 0.25 * d) * m)
        j[f"wrist_{s}"] = tuple((np.array([0.18, 0.5, 0]) + 0.5 * d) * m)
        j[f"hip_{s}"] = (0.1 * x, 0.0, 0)
        j[f"knee_{s}"] = (0.1 * x, -0.42, 0)
        j[f"ankle_{s}"] = (0.1 * x, -0.80, 0)
    joints = np.array([j[n] for n in JOINT_NAMES], float)
    J = dict(zip(JOINT_NAMES, joints, strict=True))
    pieces = [("torso", prism(np.array([0, CROTCH, 0.0]), np.array([0, 0.55, 0.0]), *TORSO,
                              up=np.array([1.0, 0, 0]))),
              ("neck", prism(np.array([0, 0.55, 0.0]), np.array([0, TOP, 0.0]), NECK))]
    for s in ("l", "r"):
        pieces.append((f"arm_{s}", prism(J[f"shoulder_{s}"], J[f"wrist_{s}"], ARM)))
        pieces.append((f"leg_{s}", prism(J[f"hip_{s}"], np.array([J[f"hip_{s}"][0], FLOOR, 0]),
                                         LEG)))
    vertices, faces, parts, offset = [], [], [], 0
    for name, (v, f) in pieces:
        vertices.append(v)
        faces.append(f + offset)
        parts.append(np.full(len(v), PARTS.index(name)))
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces), np.concatenate(parts), joints
