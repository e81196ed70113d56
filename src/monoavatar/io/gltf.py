"""glTF 2.0 binary (``.glb``) export of a skinned, textured avatar, optionally animated.

What a written file holds:

- one mesh in the canonical pose (Y up, facing +Z, metres), its vertices split at UV seams
  (glTF has a single index per corner), with ``POSITION``, ``NORMAL`` (area-weighted, smooth
  across seams), ``TEXCOORD_0`` (glTF convention: origin top-left, v down, as our UVs are),
  ``JOINTS_0`` / ``WEIGHTS_0`` (the :data:`MAX_INFLUENCES` largest skinning weights of each
  vertex, renormalised to sum to one);
- a material whose base colour is the texture, embedded as PNG;
- a skin over a node hierarchy named after the fitting skeleton. Joint nodes carry the rest
  offset to their parent as translation (the root: its rest position) and, when posed, the
  joint's local rotation, so that a node's world matrix is ``W_j = W_parent · T(c_j − c_p) ·
  R_j``; inverse bind matrices are ``T(−c_j)``. Then ``W_j · T(−c_j)`` equals the skinning
  transform ``A_j`` of :func:`monoavatar.body.lbs.joint_transforms` (rest → posed, about the
  rest joint ``c_j``), and a viewer reproduces :meth:`BodyModel.forward` exactly up to the
  4-influence limit;
- optionally an animation: per-frame joint rotations (unit quaternions, x y z w) and the root
  translation, sampled at given times in seconds, interpolated LINEAR (slerp for rotations).

Pose-dependent correctives (SMPL's B_p(θ)) cannot be expressed in a glTF skin and are left
out; Anny has none.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pygltflib as gl
import torch
from PIL import Image
from scipy.spatial.transform import Rotation

from monoavatar import __version__
from monoavatar.body.model import BodyModel
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_path
from monoavatar.io.export_mesh import texture_to_uint8

__all__ = [
    "MAX_INFLUENCES",
    "GltfExportError",
    "PoseAnimation",
    "SkinnedMesh",
    "axis_angle_quaternions",
    "GlbSkin",
    "dense_weights",
    "glb_bytes",
    "read_glb_skin",
    "limit_influences",
    "skinned_mesh_from_body",
    "split_uv_seams",
    "write_animated_glb",
    "write_avatar_glb",
]

#: Joint influences per vertex in the written skin (one JOINTS_0/WEIGHTS_0 set; what every
#: glTF viewer supports).
MAX_INFLUENCES = 4

_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_LINEAR = 9729
_LINEAR_MIPMAP_LINEAR = 9987
_CLAMP_TO_EDGE = 33071


class GltfExportError(MonoavatarError, ValueError):
    """Inconsistent input to a glTF writer (shapes, skeleton, animation)."""


@dataclass(frozen=True)
class SkinnedMesh:
    """A rigged, textured mesh in the canonical pose, ready for export.

    Attributes:
        vertices: (V, 3) canonical positions, metres (Y up, facing +Z).
        faces: (F, 3) vertex indices, counter-clockwise seen from outside.
        uv: (T, 2) texture coordinates, glTF convention (origin top-left, v down).
        face_uv: (F, 3) indices into ``uv`` per face corner.
        skin_weights: (V, J) skinning weights, rows summing to one.
        joint_names: J names.
        parents: J parent indices, ``parents[0] == -1``, ``parents[j] < j``.
        rest_joints: (J, 3) canonical rest joint positions, metres.
        texture: (H, W, 3) uint8 or float in [0, 1], or None for an untextured material.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    face_uv: np.ndarray
    skin_weights: np.ndarray
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    rest_joints: np.ndarray
    texture: np.ndarray | None = None

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def check(self) -> None:
        """Raise :class:`GltfExportError` unless the arrays are mutually consistent."""
        v, j = len(self.vertices), len(self.joint_names)
        expected: dict[str, tuple[np.ndarray, tuple[int | None, ...]]] = {
            "vertices": (self.vertices, (None, 3)),
            "faces": (self.faces, (None, 3)),
            "uv": (self.uv, (None, 2)),
            "face_uv": (self.face_uv, (len(self.faces), 3)),
            "skin_weights": (self.skin_weights, (v, j)),
            "rest_joints": (self.rest_joints, (j, 3)),
        }
        for name, (array, shape) in expected.items():
            a = np.asarray(array)
            if a.ndim != len(shape) or any(
                s is not None and s != t for s, t in zip(shape, a.shape, strict=True)
            ):
                want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
                raise GltfExportError(f"{name}: expected shape {want}, got {a.shape}")
        if len(self.parents) != j:
            raise GltfExportError(f"parents: expected {j} entries, got {len(self.parents)}")
        if (
            j == 0
            or self.parents[0] != -1
            or any(not 0 <= p < i for i, p in enumerate(self.parents) if i > 0)
        ):
            raise GltfExportError(
                f"parents must be -1 for joint 0 and smaller than each joint's index, "
                f"got {list(self.parents)}"
            )
        if len(self.faces) == 0:
            raise GltfExportError("the mesh has no faces")
        if np.asarray(self.faces).min() < 0 or np.asarray(self.faces).max() >= v:
            raise GltfExportError(f"faces index outside [0, {v})")
        if np.asarray(self.face_uv).min() < 0 or np.asarray(self.face_uv).max() >= len(self.uv):
            raise GltfExportError(f"face_uv index outside [0, {len(self.uv)})")
        if self.texture is not None:
            try:
                texture_to_uint8(self.texture)
            except ValueError as exc:
                raise GltfExportError(str(exc)) from None
        for name, array in (("vertices", self.vertices), ("skin_weights", self.skin_weights)):
            if not np.isfinite(array).all():
                raise GltfExportError(f"{name} contain non-finite values")


@dataclass(frozen=True)
class PoseAnimation:
    """A pose sequence of the skeleton, as keyframes.

    Attributes:
        poses: (N, J, 3) axis-angle (radians) local joint rotations in canonical axes, as
            :meth:`BodyModel.forward` takes them; joint 0 is the global orientation.
        translations: (N, 3) global translations, metres (as ``forward``'s ``translation``).
        times: (N,) keyframe times in seconds, strictly increasing.
        name: the animation's name in the file.
    """

    poses: np.ndarray
    translations: np.ndarray
    times: np.ndarray
    name: str = "motion"

    @staticmethod
    def from_fps(
        poses: np.ndarray,
        translations: np.ndarray | None = None,
        fps: float = 30.0,
        name: str = "motion",
    ) -> PoseAnimation:
        """Keyframes at ``k / fps`` seconds; ``translations`` None = zeros."""
        poses = np.asarray(poses, dtype=np.float64)
        if fps <= 0:
            raise GltfExportError(f"fps must be positive, got {fps}")
        if translations is None:
            translations = np.zeros((len(poses), 3))
        return PoseAnimation(
            poses=poses,
            translations=np.asarray(translations, dtype=np.float64),
            times=np.arange(len(poses)) / float(fps),
            name=name,
        )

    @property
    def num_frames(self) -> int:
        return len(self.times)

    def check(self, num_joints: int) -> None:
        """Raise :class:`GltfExportError` unless consistent with a skeleton of J joints."""
        n = len(self.times)
        if n == 0:
            raise GltfExportError("animation has no keyframes")
        if np.shape(self.poses) != (n, num_joints, 3):
            raise GltfExportError(
                f"poses: expected shape ({n}, {num_joints}, 3) axis-angle, "
                f"got {np.shape(self.poses)}"
            )
        if np.shape(self.translations) != (n, 3):
            raise GltfExportError(
                f"translations: expected shape ({n}, 3), got {np.shape(self.translations)}"
            )
        times = np.asarray(self.times, dtype=np.float64)
        if times.ndim != 1 or not np.isfinite(times).all() or (times < 0).any():
            raise GltfExportError("times must be finite, non-negative seconds, shape (N,)")
        if (np.diff(times.astype(np.float32)) <= 0).any():
            raise GltfExportError("times must be strictly increasing (also in float32)")
        if not (np.isfinite(self.poses).all() and np.isfinite(self.translations).all()):
            raise GltfExportError("poses and translations must be finite")


def skinned_mesh_from_body(
    body: BodyModel,
    shape: np.ndarray | torch.Tensor | None = None,
    offsets: np.ndarray | torch.Tensor | None = None,
    texture: np.ndarray | None = None,
) -> SkinnedMesh:
    """The canonical mesh of ``body`` with shape (S,) and offsets (V, 3) (metres, canonical;
    None = zeros), rigged with the body's skeleton and weights."""
    s = body.default_shape(1)
    if shape is not None:
        s = torch.as_tensor(shape, dtype=body.dtype, device=body.device).detach().reshape(1, -1)
        if s.shape[1] != body.shape_dim:
            raise GltfExportError(f"shape: expected {body.shape_dim} values, got {s.shape[1]}")
    with torch.no_grad():
        rest_vertices, rest_joints = body.rest_shape(s)
    vertices = rest_vertices[0].double().cpu().numpy()
    if offsets is not None:
        d = torch.as_tensor(offsets).detach().cpu().double().numpy()
        if d.shape != vertices.shape:
            raise GltfExportError(f"offsets: expected shape {vertices.shape}, got {d.shape}")
        vertices = vertices + d
    return SkinnedMesh(
        vertices=vertices,
        faces=body.faces.cpu().numpy().astype(np.int64),
        uv=body.uv.double().cpu().numpy(),
        face_uv=body.face_uv.cpu().numpy().astype(np.int64),
        skin_weights=body.skin_weights.double().cpu().numpy(),
        joint_names=tuple(body.joint_names),
        parents=tuple(int(p) for p in body.parents),
        rest_joints=rest_joints[0].double().cpu().numpy(),
        texture=texture,
    )


# -- mesh preparation ------------------------------------------------------------------------
def split_uv_seams(
    faces: np.ndarray, face_uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One output vertex per distinct (vertex, UV) corner pair.

    Args:
        faces: (F, 3) vertex indices; face_uv: (F, 3) UV indices.
    Returns:
        source_vertex (V',) the mesh vertex of each output vertex, source_uv (V',) its UV
        index, and (F, 3) faces indexing the output vertices.
    """
    faces = np.asarray(faces, dtype=np.int64)
    face_uv = np.asarray(face_uv, dtype=np.int64)
    num_uv = int(face_uv.max()) + 1
    keys = faces.ravel() * num_uv + face_uv.ravel()
    unique, inverse = np.unique(keys, return_inverse=True)
    return unique // num_uv, unique % num_uv, inverse.reshape(faces.shape)


def limit_influences(weights: np.ndarray, k: int = MAX_INFLUENCES) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest weights of each vertex, renormalised.

    Args:
        weights: (V, J) non-negative skinning weights.
    Returns:
        joints (V, k) int joint indices and weights (V, k) float64 summing to one; slots with
        zero weight have joint index 0 (as glTF asks).
    """
    weights = np.asarray(weights, dtype=np.float64)
    k_eff = min(k, weights.shape[1])
    order = np.argsort(-weights, axis=1, kind="stable")[:, :k_eff]
    top = np.take_along_axis(weights, order, axis=1)
    total = top.sum(axis=1, keepdims=True)
    if (total <= 0).any():
        raise GltfExportError("a vertex has no positive skinning weight")
    top = top / total
    joints = np.where(top > 0, order, 0)
    if k_eff < k:
        pad = ((0, 0), (0, k - k_eff))
        joints, top = np.pad(joints, pad), np.pad(top, pad)
    return joints.astype(np.int64), top


def dense_weights(joints: np.ndarray, weights: np.ndarray, num_joints: int) -> np.ndarray:
    """(V, k) joint indices and weights → (V, J) dense weights (the inverse of
    :func:`limit_influences` up to the dropped influences)."""
    dense = np.zeros((len(joints), num_joints))
    np.add.at(dense, (np.arange(len(joints))[:, None], joints), weights)
    return dense


def _float32_weights(weights: np.ndarray) -> np.ndarray:
    """Cast to float32 such that each row sums to one as closely as float32 allows."""
    w = weights.astype(np.float32)
    rest = w[:, 1:].sum(axis=1, dtype=np.float32)
    w[:, 0] = np.float32(1.0) - rest  # the largest weight absorbs the rounding
    return w


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    from monoavatar.core.geometry import vertex_normals

    n = vertex_normals(vertices, faces).numpy()
    bad = np.linalg.norm(n, axis=1) < 0.5
    n[bad] = (0.0, 1.0, 0.0)  # isolated or cancelling faces: any unit vector is valid
    return n


# -- binary assembly -------------------------------------------------------------------------
class _Builder:
    """Accumulates buffer views and accessors of one GLB buffer."""

    def __init__(self, gltf: gl.GLTF2) -> None:
        self.gltf = gltf
        self.blob = bytearray()

    def view(self, data: bytes, target: int | None = None) -> int:
        self.blob.extend(b"\0" * (-len(self.blob) % 4))
        self.gltf.bufferViews.append(
            gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data), target=target)
        )
        self.blob.extend(data)
        return len(self.gltf.bufferViews) - 1

    def accessor(
        self,
        array: np.ndarray,
        kind: str,
        target: int | None = None,
        bounds: bool = False,
    ) -> int:
        component = {
            np.dtype(np.float32): gl.FLOAT,
            np.dtype(np.uint8): gl.UNSIGNED_BYTE,
            np.dtype(np.uint16): gl.UNSIGNED_SHORT,
            np.dtype(np.uint32): gl.UNSIGNED_INT,
        }[array.dtype]
        array = np.ascontiguousarray(array)
        flat = array.reshape(len(array), -1)
        acc = gl.Accessor(
            bufferView=self.view(array.astype(array.dtype.newbyteorder("<")).tobytes(), target),
            componentType=component,
            count=len(array),
            type=kind,
        )
        if bounds:
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
            if component != gl.FLOAT:
                acc.min = [int(x) for x in acc.min]
                acc.max = [int(x) for x in acc.max]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1


def _png_bytes(texture: np.ndarray) -> bytes:
    out = io.BytesIO()
    Image.fromarray(texture_to_uint8(texture)).save(out, format="PNG")
    return out.getvalue()


def axis_angle_quaternions(poses: np.ndarray) -> np.ndarray:
    """(N, J, 3) axis-angle → (N, J, 4) unit quaternions (x, y, z, w), each joint's sequence
    kept on one hemisphere so that slerp between keyframes takes the short way."""
    n, j, _ = poses.shape
    q = Rotation.from_rotvec(poses.reshape(-1, 3)).as_quat().reshape(n, j, 4)
    for k in range(1, n):
        flip = (q[k] * q[k - 1]).sum(axis=-1) < 0
        q[k, flip] *= -1.0
    return q


def _build(mesh: SkinnedMesh, animations: Sequence[PoseAnimation] = (),
           colors: np.ndarray | None = None) -> gl.GLTF2:  # fmt: skip
    mesh.check()
    num_joints = mesh.num_joints
    for animation in animations:
        animation.check(num_joints)
    if colors is not None and np.shape(colors) != (len(mesh.vertices), 3):
        raise GltfExportError(
            f"colors: expected ({len(mesh.vertices)}, 3), got {np.shape(colors)}"
        )
    gltf = gl.GLTF2(asset=gl.Asset(generator=f"monoavatar {__version__}", version="2.0"))
    b = _Builder(gltf)

    source_vertex, source_uv, faces = split_uv_seams(mesh.faces, mesh.face_uv)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    normals = _vertex_normals(vertices, np.asarray(mesh.faces))
    joints, weights = limit_influences(np.asarray(mesh.skin_weights)[source_vertex])
    index_type = np.uint16 if len(source_vertex) < 65535 else np.uint32
    joint_type = np.uint8 if num_joints <= 256 else np.uint16
    attributes = gl.Attributes(
        POSITION=b.accessor(
            vertices[source_vertex].astype(np.float32), gl.VEC3, _ARRAY_BUFFER, bounds=True
        ),
        NORMAL=b.accessor(normals[source_vertex].astype(np.float32), gl.VEC3, _ARRAY_BUFFER),
        TEXCOORD_0=b.accessor(
            np.asarray(mesh.uv)[source_uv].astype(np.float32), gl.VEC2, _ARRAY_BUFFER
        ),
        JOINTS_0=b.accessor(joints.astype(joint_type), gl.VEC4, _ARRAY_BUFFER),
        WEIGHTS_0=b.accessor(_float32_weights(weights), gl.VEC4, _ARRAY_BUFFER),
    )
    if colors is not None:
        attributes.COLOR_0 = b.accessor(
            np.clip(np.asarray(colors, dtype=np.float32)[source_vertex], 0.0, 1.0), gl.VEC3,
            _ARRAY_BUFFER,
        )
    indices = b.accessor(
        faces.reshape(-1).astype(index_type), gl.SCALAR, _ELEMENT_ARRAY_BUFFER, bounds=True
    )

    pbr = gl.PbrMetallicRoughness(
        baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0, roughnessFactor=1.0
    )
    if mesh.texture is not None:
        image_view = b.view(_png_bytes(mesh.texture))
        gltf.images.append(gl.Image(bufferView=image_view, mimeType="image/png", name="texture"))
        gltf.samplers.append(
            gl.Sampler(
                magFilter=_LINEAR,
                minFilter=_LINEAR_MIPMAP_LINEAR,
                wrapS=_CLAMP_TO_EDGE,
                wrapT=_CLAMP_TO_EDGE,
            )
        )
        gltf.textures.append(gl.Texture(sampler=0, source=0, name="texture"))
        pbr.baseColorTexture = gl.TextureInfo(index=0)
    gltf.materials.append(gl.Material(pbrMetallicRoughness=pbr, name="skin"))
    gltf.meshes.append(
        gl.Mesh(
            name="avatar",
            primitives=[gl.Primitive(attributes=attributes, indices=indices, material=0)],
        )
    )

    # nodes: 0 = the skinned mesh (a root without transform, as glTF asks), 1.. = joints
    rest = np.asarray(mesh.rest_joints, dtype=np.float64)
    gltf.nodes.append(gl.Node(name="avatar", mesh=0, skin=0))
    joint_node = [1 + j for j in range(num_joints)]
    for j, (name, parent) in enumerate(zip(mesh.joint_names, mesh.parents, strict=True)):
        offset = rest[j] if parent < 0 else rest[j] - rest[parent]
        gltf.nodes.append(gl.Node(name=name, translation=[float(x) for x in offset]))
        if parent >= 0:
            children = gltf.nodes[joint_node[parent]].children
            assert children is not None
            children.append(joint_node[j])
    inverse_bind = np.tile(np.eye(4, dtype=np.float32), (num_joints, 1, 1))
    inverse_bind[:, :3, 3] = -rest
    gltf.skins.append(
        gl.Skin(
            name="skeleton",
            # column-major storage: the transpose of a row-major matrix, written row by row
            inverseBindMatrices=b.accessor(inverse_bind.transpose(0, 2, 1).copy(), gl.MAT4),
            skeleton=joint_node[0],
            joints=joint_node,
        )
    )
    gltf.scenes.append(gl.Scene(name="avatar", nodes=[0, joint_node[0]]))
    gltf.scene = 0

    for animation in animations:
        poses = np.asarray(animation.poses, dtype=np.float64)
        times = b.accessor(np.asarray(animation.times, dtype=np.float32), gl.SCALAR, bounds=True)
        quats = axis_angle_quaternions(poses).astype(np.float32)
        root = rest[0] + np.asarray(animation.translations, dtype=np.float64)
        anim = gl.Animation(name=animation.name)
        anim.samplers.append(
            gl.AnimationSampler(
                input=times,
                output=b.accessor(root.astype(np.float32), gl.VEC3),
                interpolation=gl.ANIM_LINEAR,
            )
        )
        anim.channels.append(
            gl.AnimationChannel(
                sampler=0, target=gl.AnimationChannelTarget(node=joint_node[0], path="translation")
            )
        )
        for j in range(num_joints):
            anim.samplers.append(
                gl.AnimationSampler(
                    input=times,
                    output=b.accessor(np.ascontiguousarray(quats[:, j]), gl.VEC4),
                    interpolation=gl.ANIM_LINEAR,
                )
            )
            anim.channels.append(
                gl.AnimationChannel(
                    sampler=len(anim.samplers) - 1,
                    target=gl.AnimationChannelTarget(node=joint_node[j], path="rotation"),
                )
            )
        gltf.animations.append(anim)

    b.blob.extend(b"\0" * (-len(b.blob) % 4))
    gltf.buffers.append(gl.Buffer(byteLength=len(b.blob)))
    gltf.set_binary_blob(bytes(b.blob))
    return gltf


# -- writers ---------------------------------------------------------------------------------
def glb_bytes(mesh: SkinnedMesh, animations: Sequence[PoseAnimation] = (),
              colors: np.ndarray | None = None) -> bytes:  # fmt: skip
    """``mesh`` as a glTF 2.0 binary in memory, with ``animations`` (each a named glTF
    animation) and, given ``colors`` (V, 3) RGB in [0, 1] per mesh vertex, a ``COLOR_0``
    attribute."""
    return b"".join(_build(mesh, animations, colors).save_to_bytes())


def write_avatar_glb(
    path: str | Path, mesh: SkinnedMesh, animation: PoseAnimation | None = None
) -> Path:
    """Write ``mesh`` (and ``animation`` if given) as a glTF 2.0 binary.

    The file is written under a temporary name and renamed, so a failure leaves no partial
    file (and an existing file at ``path`` untouched). Returns ``path``.
    """
    path = Path(path)
    chunks: Sequence[bytes] = _build(mesh, () if animation is None else (animation,)
                                     ).save_to_bytes()  # fmt: skip
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        for chunk in chunks:
            fh.write(chunk)
    return path


def write_animated_glb(path: str | Path, mesh: SkinnedMesh, animation: PoseAnimation) -> Path:
    """Write ``mesh`` with ``animation`` (required) as a glTF 2.0 binary; see
    :func:`write_avatar_glb`."""
    return write_avatar_glb(path, mesh, animation)


@dataclass(frozen=True)
class GlbSkin:
    """What a viewer needs to know of a skinned glb: ``joint_names`` (J,) in skin order,
    ``positions`` (N, 3) float32 the mesh's vertex positions (after seam splitting),
    ``rest_root`` (3,) the root joint node's rest translation, metres, and the names of its
    ``animations``."""

    joint_names: tuple[str, ...]
    positions: np.ndarray
    rest_root: np.ndarray
    animations: tuple[str, ...]


def read_glb_skin(payload: bytes) -> GlbSkin:
    """Read :class:`GlbSkin` from a glTF binary with one skinned mesh (as this module writes).

    Raises:
        GltfExportError: not a glb, or no skinned mesh in it.
    """
    try:
        gltf = gl.GLTF2.load_from_bytes(payload)
    except Exception as exc:  # pygltflib raises bare errors of several kinds
        raise GltfExportError(f"not a glTF binary ({exc})") from exc
    if not gltf.skins or not gltf.meshes:
        raise GltfExportError("the glb holds no skinned mesh")
    names = tuple(str(gltf.nodes[j].name) for j in gltf.skins[0].joints)
    accessor = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    view = gltf.bufferViews[accessor.bufferView]
    blob = gltf.binary_blob()
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    positions = np.frombuffer(blob, dtype=np.float32, count=3 * accessor.count,
                              offset=start).reshape(-1, 3)  # fmt: skip
    root = np.asarray(gltf.nodes[gltf.skins[0].joints[0]].translation or [0.0, 0.0, 0.0],
                      dtype=np.float64)  # fmt: skip
    return GlbSkin(names, positions.copy(), root, tuple(str(a.name) for a in gltf.animations))
