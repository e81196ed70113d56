"""Texture stage (Sec. B.3.4) on a ``monoavatar synth`` scene: speed and held-out PSNR.

The avatar is the coarse, unclothed ``"anny"`` body with the scene's true phenotype (the first
six shape parameters of its ``anny-local`` subject) posed with the true poses and translations,
so geometry is realistic but imperfect (no clothing, hair volume or local shape changes). The
texture is built from the key frames (every ``--step``-th even frame) and evaluated on held-out
odd frames: the textured avatar is rendered in each held-out pose and compared with the frame by
PSNR over the pixels that both the render and the true person mask cover (intersection).

Three variants:

- ``albedo, true SH``: the scene's lighting is divided out when building and re-applied when
  rendering (an upper bound for the lighting part);
- ``albedo, estimated SH``: lighting from :func:`monoavatar.texture.estimate_sh` on the key
  frames, used for both (what a real pipeline can do);
- ``raw colours, unlit``: observed colours, rendered without lighting.

Writes ``texture_*.png`` and ``preview_*.png`` (GT frame | render over the frame | render alone,
cropped to the person) for a few held-out frames into ``--out``.

Run: ``python benchmarks/bench_texture.py SCENE [--out DIR] [--size 1024] [--step 1]
[--time-all]`` (one thread: ``OMP_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from monoavatar.body import load_body_model
from monoavatar.datasets.synth_scene import read_synth_scene
from monoavatar.eval import psnr
from monoavatar.render import rasterize, render_textured
from monoavatar.texture import TextureSettings, UVTexture, build_texture, estimate_sh


def _crop_box(masks: list[np.ndarray], pad: int = 8) -> tuple[int, int, int, int]:
    union = np.logical_or.reduce(masks)
    rows, cols = np.nonzero(union)
    h, w = union.shape
    return (
        max(rows.min() - pad, 0),
        min(rows.max() + pad + 1, h),
        max(cols.min() - pad, 0),
        min(cols.max() + pad + 1, w),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--out", type=Path, default=Path("bench_texture_out"))
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--sample-size", type=int, default=None)
    parser.add_argument("--step", type=int, default=1, help="key frames: every step-th even frame")
    parser.add_argument("--sh-step", type=int, default=2, help="estimate_sh: every n-th key frame")
    parser.add_argument(
        "--time-all", action="store_true", help="also time build_texture on every frame"
    )
    parser.add_argument("--held-every", type=int, default=4, help="use every n-th odd frame")
    parser.add_argument("--previews", type=int, default=4)
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)

    scene = read_synth_scene(args.scene)
    gt = scene.ground_truth
    sh_true = np.load(args.scene / "gt" / "params.npz")["sh"]
    body = load_body_model("anny")
    n = len(gt.poses)
    shape = torch.zeros(n, body.shape_dim)
    shape[:, :6] = torch.as_tensor(gt.shapes[gt.subject_of_frame][:, :6], dtype=torch.float32)
    with torch.no_grad():
        vertices = body(
            shape=shape,
            pose=torch.as_tensor(gt.poses, dtype=torch.float32),
            translation=torch.as_tensor(gt.translations, dtype=torch.float32),
        ).vertices.numpy()
    faces, uv, face_uv = body.faces.numpy(), body.uv.numpy(), body.face_uv.numpy()
    images, masks = scene.frames.images, scene.observations.masks
    key = np.arange(0, n, 2)[:: args.step]
    held = np.arange(1, n, 2)[:: args.held_every]
    settings = TextureSettings(size=args.size, sample_size=args.sample_size)

    def build(sh: np.ndarray | None) -> tuple[UVTexture, float]:
        start = time.perf_counter()
        tex = build_texture(
            vertices[key],
            faces,
            uv,
            face_uv,
            images[key],
            masks[key],
            scene.camera,
            sh=sh,
            settings=settings,
        )
        return tex, time.perf_counter() - start

    start = time.perf_counter()
    sh_key = key[:: args.sh_step]
    sh_est = estimate_sh(vertices[sh_key], faces, images[sh_key], masks[sh_key], scene.camera)
    t_sh = time.perf_counter() - start

    variants = {
        "albedo_true_sh": (sh_true[key], lambda i: sh_true[i]),
        "albedo_estimated_sh": (sh_est, lambda i: sh_est),
        "raw_unlit": (None, lambda i: None),
    }
    frags = {int(i): rasterize(vertices[i], faces, scene.camera) for i in held}
    iou = np.mean(
        [
            (frags[i].mask.numpy() & masks[i]).sum() / (frags[i].mask.numpy() | masks[i]).sum()
            for i in frags
        ]
    )
    print(
        f"scene {args.scene}: {n} frames {scene.camera.width}x{scene.camera.height}; "
        f"{len(key)} key frames, {len(held)} held-out; body/GT silhouette IoU {iou:.3f}"
    )
    print(f"estimate_sh on {len(sh_key)} frames: {t_sh:.2f} s")
    box = _crop_box([masks[i] | frags[i].mask.numpy() for i in frags])
    picks = held[np.linspace(0, len(held) - 1, min(args.previews, len(held))).astype(int)]
    for name, (sh_build, sh_render) in variants.items():
        tex, seconds = build(sh_build)
        scores, tiles = [], []
        for i in held:
            fr = frags[int(i)]
            render = render_textured(
                vertices[i],
                faces,
                fr,
                uv,
                face_uv,
                torch.from_numpy(tex.as_float()),
                sh=sh_render(i),
            )
            img = np.clip(render.numpy(), 0.0, 1.0)
            truth = images[i].astype(np.float32) / 255.0
            scores.append(psnr(img, truth, fr.mask.numpy() & masks[i]))
            if i in picks:
                ours = (img * 255 + 0.5).astype(np.uint8)
                over = images[i].copy()
                over[fr.mask.numpy()] = ours[fr.mask.numpy()]
                r0, r1, c0, c1 = box
                tiles.append(
                    np.concatenate(
                        [images[i][r0:r1, c0:c1], over[r0:r1, c0:c1], ours[r0:r1, c0:c1]], axis=1
                    )
                )
        Image.fromarray(tex.image).save(args.out / f"texture_{name}.png")
        Image.fromarray(np.concatenate(tiles, axis=0)).save(args.out / f"preview_{name}.png")
        seen = tex.coverage[tex.chart].mean()
        print(
            f"{name:22s} build {seconds:5.2f} s  PSNR {np.mean(scores):5.2f} dB "
            f"(min {np.min(scores):5.2f})  texels seen {100 * seen:.1f} %"
        )
    if args.time_all:
        start = time.perf_counter()
        everything = np.arange(n)
        estimate_sh(vertices[everything[::4]], faces, images[::4], masks[::4], scene.camera)
        mid = time.perf_counter()
        build_texture(
            vertices, faces, uv, face_uv, images, masks, scene.camera, sh=sh_est, settings=settings
        )
        end = time.perf_counter()
        print(
            f"all {n} frames: estimate_sh (every 4th) {mid - start:.2f} s + "
            f"build_texture {end - mid:.2f} s = {end - start:.2f} s"
        )
    print(f"outputs in {args.out}")


if __name__ == "__main__":
    main()
