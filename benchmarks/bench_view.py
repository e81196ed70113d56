"""Frames per second of the ``monoavatar view`` page in headless Chromium with software WebGL
(SwiftShader), for avatars of 14k (Anny as it is), 55k and 220k vertices (subdivided once and
twice), each textured, skinned and playing the built-in walk.

Each page is opened at 1200 x 700 with ``#layout=orbit&bench=N``: the page renders N frames
one after the other (advancing the walk by 1/30 s each, reading a pixel back so that each frame
is finished) and reports N over the time taken. Written to ``--out/view_fps.json``.

Run: ``python benchmarks/bench_view.py --out DIR`` (needs ``chromium``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.browser import Browser  # noqa: E402

from monoavatar.body import load_body_model  # noqa: E402
from monoavatar.body.subdivide import subdivide  # noqa: E402
from monoavatar.io.gltf import (  # noqa: E402
    SkinnedMesh,
    glb_bytes,
    read_glb_skin,
    skinned_mesh_from_body,
)
from monoavatar.io.viewer_page import ViewerPage, write_page  # noqa: E402
from monoavatar.pipelines.motions import walk_motion  # noqa: E402
from monoavatar.pipelines.view import motion_clip, page_data  # noqa: E402


def _subdivided(mesh: SkinnedMesh, levels: int) -> SkinnedMesh:
    vertices = torch.as_tensor(mesh.vertices)[None]
    faces, uv = torch.as_tensor(mesh.faces), torch.as_tensor(mesh.uv)
    face_uv, weights = torch.as_tensor(mesh.face_uv), torch.as_tensor(mesh.skin_weights)
    for _ in range(levels):
        sub = subdivide(faces, uv, face_uv, weights)
        vertices = sub.apply(vertices)
        faces, uv, face_uv, weights = sub.faces, sub.uv, sub.face_uv, sub.weights
    return SkinnedMesh(vertices[0].numpy(), faces.numpy(), uv.numpy(), face_uv.numpy(),
                       weights.numpy(), mesh.joint_names, mesh.parents, mesh.rest_joints,
                       mesh.texture)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=120, help="frames rendered per page")
    parser.add_argument("--hash", default="", help="more page settings, e.g. &shading=albedo")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    body = load_body_model("anny", dtype=torch.float64)
    texture = np.random.default_rng(0).integers(0, 256, (1024, 1024, 3), dtype=np.uint8)
    base = skinned_mesh_from_body(body, texture=texture)
    walk = walk_motion(body)
    rows = []
    with tempfile.TemporaryDirectory() as tmp, Browser(1200, 700) as browser:
        for levels in (0, 1, 2):
            mesh = _subdivided(base, levels)
            glb = glb_bytes(mesh)
            data = page_data(f"bench {levels}", [], read_glb_skin(glb),
                             [motion_clip("walk", walk, mesh.joint_names, world=False)])
            page = write_page(Path(tmp) / f"page{levels}.html", ViewerPage(glb, data))
            start = time.monotonic()
            state = browser.open(f"{page.as_uri()}#layout=orbit&bench={args.frames}{args.hash}",
                                 timeout=600)  # fmt: skip
            seconds = time.monotonic() - start
            if state != "ready":
                raise SystemExit(f"page {levels}: {state}")
            fps = float(browser.evaluate("document.body.dataset.fps"))
            vertices = int(browser.evaluate("document.body.dataset.vertices"))
            proxy = browser.evaluate("document.body.dataset.proxyVertices")
            rows.append({"vertices": vertices, "faces": int(len(mesh.faces)),
                         "page_mb": round(page.stat().st_size / 1e6, 1), "fps": round(fps, 1),
                         "proxy_vertices": None if proxy is None else int(proxy),
                         "open_and_bench_s": round(seconds, 1)})  # fmt: skip
            print(f"{vertices:>8} vertices  {len(mesh.faces):>8} faces  "
                  f"{rows[-1]['page_mb']:>5} MB  {fps:6.1f} frames/s  (moving as "
                  f"{proxy or vertices} vertices)")
    (args.out / "view_fps.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
