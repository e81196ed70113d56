"""Speed of the CPU renderer on a human-sized mesh, one thread.

An "ellipsoid person" (head, torso, arms, legs; 13.5k vertices, 27k triangles, 1.7 m tall) stands
2.5 m in front of a 540x540 camera with a 600 px focal length, so it fills most of the image
height — the size of one frame of a People-Snapshot-style video. Times rasterisation,
interpolation of vertex normals, SH shading, and a full textured render (UVs, bilinear texture
lookup, normals, SH) with ``torch.set_num_threads(1)``, and prints the median over the runs.

Run: ``python benchmarks/bench_render.py [--runs 20]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch
import trimesh

from monoavatar.core.camera import PinholeCamera
from monoavatar.render import (
    Fragments,
    interpolate_masked,
    rasterize,
    render_textured,
    sample_sh_lighting,
    scatter_masked,
    sh_shading,
    vertex_normals,
)


def ellipsoid_person() -> trimesh.Trimesh:
    """A 1.7 m tall person made of ellipsoids (icospheres scaled per axis), feet at y=0,
    facing +z (Y-up); 13,452 vertices and 26,880 triangles, close to Anny's 13,718 / 27,420."""
    parts = [
        # (icosphere subdivisions, semi-axes (x, y, z), centre, tilt about z in radians)
        (3, (0.09, 0.115, 0.10), (0.0, 1.585, 0.0), 0.0),  # head
        (4, (0.18, 0.34, 0.11), (0.0, 1.16, 0.0), 0.0),  # torso
        (4, (0.05, 0.31, 0.05), (-0.29, 1.16, 0.0), -0.25),  # right arm
        (4, (0.05, 0.31, 0.05), (0.29, 1.16, 0.0), 0.25),  # left arm
        (4, (0.08, 0.44, 0.08), (-0.10, 0.44, 0.0), -0.04),  # right leg
        (4, (0.08, 0.44, 0.08), (0.10, 0.44, 0.0), 0.04),  # left leg
    ]
    meshes = []
    for subdivisions, axes, centre, tilt in parts:
        m = trimesh.creation.icosphere(subdivisions=subdivisions)
        m.apply_scale(axes)
        m.apply_transform(trimesh.transformations.rotation_matrix(tilt, [0.0, 0.0, 1.0]))
        m.apply_translation(centre)
        meshes.append(m)
    person = trimesh.util.concatenate(meshes)
    assert isinstance(person, trimesh.Trimesh)
    return person


def median_ms(fn: Callable[[], object], runs: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(1)

    mesh = ellipsoid_person()
    vertices = torch.as_tensor(mesh.vertices, dtype=torch.float32)
    faces = torch.as_tensor(mesh.faces, dtype=torch.int64)
    # Camera 2.5 m in front of the person (at z = +2.5, chest height) looking along -z:
    # image x = world x, image y = -world y.
    R = np.diag([1.0, -1.0, -1.0])
    eye = np.array([0.0, 0.85, 2.5])
    camera = PinholeCamera.from_focal(600.0, 540, 540, R=R, t=-R @ eye)
    sh = torch.as_tensor(sample_sh_lighting(np.random.default_rng(0), 1).sh[0])
    # Per-vertex UVs and a 1024^2 texture, as for a textured avatar.
    uv = torch.rand(vertices.shape[0], 2, generator=torch.Generator().manual_seed(0))
    texture = torch.rand(1024, 1024, 3, generator=torch.Generator().manual_seed(1))

    fragments = rasterize(vertices, faces, camera)
    coverage = float(fragments.mask.float().mean())

    def raster_only() -> object:
        return rasterize(vertices, faces, camera)

    def interpolate_normals_and_shade() -> object:
        normals = interpolate_masked(vertex_normals(vertices, faces), faces, fragments)
        shading = sh_shading(torch.nn.functional.normalize(normals, dim=-1), sh)
        return scatter_masked(shading, fragments)

    def textured(frags: Fragments) -> object:
        return render_textured(vertices, faces, frags, uv, faces, texture, sh)

    rows = [
        ("rasterize", raster_only),
        ("vertex normals + interpolate + SH shading", interpolate_normals_and_shade),
        ("render_textured (uv, texture, normals, SH)", lambda: textured(fragments)),
        (
            "frame: rasterize + render_textured",
            lambda: textured(rasterize(vertices, faces, camera)),
        ),
    ]
    print(
        f"mesh: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles; "
        f"image {camera.width}x{camera.height}, coverage {100 * coverage:.1f} %; "
        f"torch threads {torch.get_num_threads()}; median of {args.runs} runs"
    )
    for name, fn in rows:
        print(f"{name:44s} {median_ms(fn, args.runs):7.1f} ms")


if __name__ == "__main__":
    main()
