"""Mesh files: Wavefront OBJ with separately indexed UVs (+ MTL + texture PNG) and its reader,
binary PLY, and an MP4 writer. Every writer writes to a temporary name and renames, so a
failure leaves no half-written file."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from monoavatar.core.errors import InputFormatError, InputNotFoundError
from monoavatar.core.files import atomic_path


def texture_to_uint8(texture: np.ndarray) -> np.ndarray:
    """A texture image (H, W, 3|4), float in [0, 1] (clipped) or uint8, as uint8."""
    texture = np.asarray(texture)
    if texture.ndim != 3 or texture.shape[2] not in (3, 4):
        raise ValueError(f"texture: expected shape (H, W, 3) or (H, W, 4), got {texture.shape}")
    if texture.dtype == np.uint8:
        return texture
    return (np.clip(texture, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_obj(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    uv: np.ndarray | None = None,
    face_uv: np.ndarray | None = None,
    texture: np.ndarray | None = None,
) -> None:
    """Write an OBJ (metres). UVs are given in glTF convention (v down) and written in OBJ's
    (v up). With a texture (H, W, 3) float in [0, 1] or uint8, also writes ``NAME.mtl`` and
    ``NAME.png`` beside it."""
    path = Path(path)
    lines = ["# monoavatar mesh, metres, Y up, facing +Z\n"]
    if texture is not None:
        lines.append(f"mtllib {path.stem}.mtl\nusemtl skin\n")
    lines.extend(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices)
    if uv is not None and face_uv is not None:
        lines.extend(f"vt {u:.6f} {1.0 - v:.6f}\n" for u, v in uv)
        for f, t in zip(faces + 1, face_uv + 1, strict=True):
            lines.append(f"f {f[0]}/{t[0]} {f[1]}/{t[1]} {f[2]}/{t[2]}\n")
    else:
        lines.extend(f"f {a} {b} {c}\n" for a, b, c in faces + 1)
    if texture is not None:
        with atomic_path(path.with_suffix(".png")) as tmp:
            Image.fromarray(texture_to_uint8(texture)).save(tmp, format="PNG")
        with atomic_path(path.with_suffix(".mtl")) as tmp:
            tmp.write_text(f"newmtl skin\nKd 1 1 1\nmap_Kd {path.stem}.png\n")
    with atomic_path(path) as tmp:
        tmp.write_text("".join(lines))


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Binary little-endian PLY of a triangle mesh (float32 vertices, metres)."""
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment monoavatar, metres\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face_rec = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_rec["n"] = 3
    face_rec["idx"] = faces
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.asarray(vertices, dtype="<f4").tobytes())
        fh.write(face_rec.tobytes())


def write_mp4(path: str | Path, frames: Sequence[np.ndarray], fps: float = 30.0,
              crf: float | None = None) -> None:  # fmt: skip
    """Encode RGB uint8 frames (H, W, 3), H and W even, as H.264 (MPEG-4 part 2 if H.264 is
    unavailable); ``crf``: H.264's constant rate factor (0 lossless … 51; None: the
    encoder's default, 23), higher is smaller and coarser."""
    import av

    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            try:
                stream = container.add_stream("libx264", rate=round(fps))
                if crf is not None:
                    stream.options = {"crf": f"{crf:g}"}
            except (av.error.FFmpegError, ValueError):  # pragma: no cover - build dependent
                stream = container.add_stream("mpeg4", rate=round(fps))
            stream.height, stream.width = frames[0].shape[:2]
            stream.pix_fmt = "yuv420p"
            for image in frames:
                for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)


def read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and triangles (F, 3) int64 of an OBJ file.

    Only ``v`` and ``f`` records are read (texture coordinates and normals are ignored, so no
    vertex is duplicated at a UV seam); polygons are split into fans; indices may be negative
    (relative), as the format allows.
    """
    path = Path(path)
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    if not path.is_file():
        raise InputNotFoundError(path, "no such mesh file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(path, f"cannot read ({exc})") from exc
    for line in text.splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not vertices or not faces:
        raise InputFormatError(path, "no vertices or no faces")
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
