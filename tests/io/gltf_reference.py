"""An independent glTF reader and skinning reference for the tests, in plain NumPy.

pygltflib only parses the JSON and splits the GLB chunks; accessors, node TRS, quaternions,
the node hierarchy and linear blend skinning are decoded and computed here from the glTF 2.0
specification, without any monoavatar code. Also runs the Khronos validator when available.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pygltflib

REPO = Path(__file__).resolve().parents[2]
VALIDATOR_SCRIPT = Path(__file__).with_name("gltf_validator.mjs")
VALIDATOR_PACKAGE = REPO / "node_modules" / "gltf-validator"
VALIDATOR_INSTALL = "npm install --no-save --prefix . gltf-validator@2.0.0-dev.3.10"

_COMPONENT = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


@dataclass
class Glb:
    gltf: pygltflib.GLTF2
    blob: bytes

    @staticmethod
    def load(path: str | Path) -> Glb:
        gltf = pygltflib.GLTF2.load_binary(str(path))
        blob = gltf.binary_blob()
        assert blob is not None
        return Glb(gltf, blob)

    def accessor(self, index: int) -> np.ndarray:
        """Decode an accessor (no sparse storage) to an array (count, width) or (count,)."""
        acc = self.gltf.accessors[index]
        view = self.gltf.bufferViews[acc.bufferView]
        dtype = np.dtype(_COMPONENT[acc.componentType])
        width = _WIDTH[acc.type]
        stride = view.byteStride or dtype.itemsize * width
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        out = (
            np.stack(
                [
                    np.frombuffer(self.blob, dtype, width, start + i * stride)
                    for i in range(acc.count)
                ]
            )
            if stride != dtype.itemsize * width
            else np.frombuffer(self.blob, dtype, width * acc.count, start).reshape(acc.count, width)
        )
        assert start + stride * (acc.count - 1) + dtype.itemsize * width <= (
            (view.byteOffset or 0) + view.byteLength
        ), "accessor runs past its buffer view"
        return out[:, 0] if width == 1 else out

    def buffer_view_bytes(self, index: int) -> bytes:
        view = self.gltf.bufferViews[index]
        start = view.byteOffset or 0
        return self.blob[start : start + view.byteLength]

    def primitive(self) -> pygltflib.Primitive:
        return self.gltf.meshes[0].primitives[0]

    def attribute(self, name: str) -> np.ndarray:
        return self.accessor(getattr(self.primitive().attributes, name))

    def indices(self) -> np.ndarray:
        return self.accessor(self.primitive().indices).reshape(-1, 3).astype(np.int64)


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternion (x, y, z, w), normalised here → (..., 3, 3)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rodrigues(axis_angle: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle → (..., 3, 3)."""
    theta = np.linalg.norm(axis_angle, axis=-1, keepdims=True)
    k = axis_angle / np.maximum(theta, 1e-300)
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    K = np.stack(
        [
            np.stack([zero, -kz, ky], -1),
            np.stack([kz, zero, -kx], -1),
            np.stack([-ky, kx, zero], -1),
        ],
        -2,
    )
    s, c = np.sin(theta)[..., None], np.cos(theta)[..., None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def node_local(
    node: pygltflib.Node, rotation: np.ndarray | None = None, translation: np.ndarray | None = None
) -> np.ndarray:
    """4×4 local matrix of a node from its TRS (or matrix), with optional overrides: rotation
    a 3×3 matrix, translation a 3-vector (what an animation channel would set)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    r = rotation
    if r is None:
        r = np.eye(3) if node.rotation is None else quaternion_matrix(np.asarray(node.rotation))
    s = np.ones(3) if node.scale is None else np.asarray(node.scale, dtype=np.float64)
    m[:3, :3] = r * s[None, :]
    t = translation
    if t is None:
        t = np.zeros(3) if node.translation is None else np.asarray(node.translation)
    m[:3, 3] = t
    return m


def world_matrices(
    glb: Glb,
    rotations: dict[int, np.ndarray] | None = None,
    translations: dict[int, np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Global matrix of every node (by node index), walking the scene graph from its roots."""
    nodes = glb.gltf.nodes
    rotations = rotations or {}
    translations = translations or {}
    world: list[np.ndarray | None] = [None] * len(nodes)

    def visit(i: int, parent: np.ndarray) -> None:
        world[i] = parent @ node_local(nodes[i], rotations.get(i), translations.get(i))
        for c in nodes[i].children or []:
            visit(c, world[i])  # type: ignore[arg-type]

    for root in glb.gltf.scenes[glb.gltf.scene].nodes:
        visit(root, np.eye(4))
    assert all(w is not None for w in world), "a node is not reachable from the scene"
    return world  # type: ignore[return-value]


def skin_vertices(
    glb: Glb,
    rotations: dict[int, np.ndarray] | None = None,
    translations: dict[int, np.ndarray] | None = None,
) -> np.ndarray:
    """Posed POSITIONs (V, 3) by glTF skinning: jointMatrix_j = inverse(global of the mesh
    node) · global(joint j) · inverseBind_j; vertex = Σ_k w_k jointMatrix_{joints_k} · p."""
    world = world_matrices(glb, rotations, translations)
    skin = glb.gltf.skins[0]
    mesh_node = next(i for i, n in enumerate(glb.gltf.nodes) if n.mesh is not None)
    ibm = glb.accessor(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    inv_mesh = np.linalg.inv(world[mesh_node])
    joint_mats = np.stack([inv_mesh @ world[n] @ ibm[j] for j, n in enumerate(skin.joints)])
    pos = glb.attribute("POSITION").astype(np.float64)
    joints = glb.attribute("JOINTS_0").astype(np.int64)
    weights = glb.attribute("WEIGHTS_0").astype(np.float64)
    blend = np.einsum("vk,vkmn->vmn", weights, joint_mats[joints])
    return np.einsum("vmn,vn->vm", blend[:, :3, :3], pos) + blend[:, :3, 3]


def animation_keyframe(glb: Glb, k: int) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """Node rotations (3×3) and translations at keyframe k of the first animation."""
    anim = glb.gltf.animations[0]
    rotations: dict[int, np.ndarray] = {}
    translations: dict[int, np.ndarray] = {}
    for ch in anim.channels:
        sampler = anim.samplers[ch.sampler]
        values = glb.accessor(sampler.output).astype(np.float64)
        if ch.target.path == "rotation":
            rotations[ch.target.node] = quaternion_matrix(values[k])
        elif ch.target.path == "translation":
            translations[ch.target.node] = values[k]
        else:  # pragma: no cover - the writer animates nothing else
            raise AssertionError(f"unexpected channel path {ch.target.path}")
    return rotations, translations


def validator_available() -> str | None:
    """None when node and the gltf-validator package are present, else the reason."""
    if shutil.which("node") is None:
        return "node is not installed (CI installs Node.js 20)"
    if not VALIDATOR_PACKAGE.is_dir():
        return f"npm package gltf-validator missing; install it with `{VALIDATOR_INSTALL}`"
    return None


def validate(path: Path) -> dict:
    """The Khronos validator's report for ``path`` as a dict."""
    node = shutil.which("node")
    assert node is not None
    done = subprocess.run(
        [node, str(VALIDATOR_SCRIPT), str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)
