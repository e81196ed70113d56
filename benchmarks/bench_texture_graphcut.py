"""Texture merging, median vs semantic graph cut (Sec. B.3.4 vs C.3.4), on ``monoavatar synth``
turn-around scenes: held-out PSNR and SSIM, colour spilling, time.

The avatar is the coarse, unclothed ``"anny"`` body with each scene's true phenotype (first six
shape parameters) posed with the true poses, optionally perturbed by ``--pose-noise`` degrees
per joint (a fitter's error), so it is misaligned as a fitted avatar is: no clothing, hair
volume or local shape. Lighting is estimated as in ``reconstruct`` and divided out. Texture
from ``--keyframes`` frames spread over the turn; held-out frames are every 4th of the others.

*Colour spilling*: the share of seen chart texels whose colour falls in another garment class
(skin, top, bottom, hair, shoes) than the ground truth's at that texel. A k-nearest-neighbour
classifier in CIELab is trained per scene on the ground-truth texture with its garment labels;
our texture is first matched to it by a per-channel gain (albedo is known up to scale). The
classifier's own error on the ground-truth texture is reported as the floor.

Scenes are made with ``monoavatar synth`` settings (``--seeds``, ``--clothing``) into
``--scenes``; tune on seeds outside the benchmark suite, report on the suite's subjects
(``--suite``).

Run: ``python benchmarks/bench_texture_graphcut.py --suite --out DIR`` or
``... --seeds 41 43 --clothing tshirt-shorts``; ``OMP_NUM_THREADS=2``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from monoavatar.bench.suite import FULL_SUBJECTS, BenchSubject, ensure_scene
from monoavatar.body import load_body_model
from monoavatar.body.lbs import axis_angle_to_matrix, matrix_to_axis_angle
from monoavatar.datasets.synth_scene import read_synth_scene
from monoavatar.eval import psnr
from monoavatar.learn.losses import ssim_map
from monoavatar.learn.uvmaps import rasterise_vertex_values, uv_layout
from monoavatar.render import rasterize, render_textured
from monoavatar.texture import TextureSettings, build_texture, estimate_sh
from monoavatar.texture.graphcut import to_lab


def _perturb(poses: np.ndarray, degrees: float, jitter: float, seed: int) -> np.ndarray:
    """(N, J, 3) axis-angle poses each rotated by a random axis-angle per joint: ``degrees``
    RMS shared by all frames plus a slow drift (the smooth part of a fitter's error), and
    ``jitter`` degrees RMS drawn per frame."""
    if degrees <= 0 and jitter <= 0:
        return poses
    rng = np.random.default_rng(seed)
    n, j, _ = poses.shape
    base = rng.normal(0, np.radians(degrees) / np.sqrt(3 * 2), (j, 3))
    drift = rng.normal(0, np.radians(degrees) / np.sqrt(3 * 2), (j, 3))
    phase = np.sin(np.linspace(0, 2 * np.pi, n))[:, None, None]
    per_frame = rng.normal(0, np.radians(jitter) / np.sqrt(3), (n, j, 3))
    noise = torch.as_tensor(base[None] + phase * drift[None] + per_frame)
    R = axis_angle_to_matrix(noise) @ axis_angle_to_matrix(torch.as_tensor(poses))
    return matrix_to_axis_angle(R).numpy()


def _labels_and_texture(scene_dir: Path, body, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth at ``size``: (S, S) garment label per texel (-1 outside the charts) and the
    (S, S, 3) albedo texture in [0, 1]."""
    import cv2

    gt = np.load(scene_dir / "gt" / "params.npz")
    layout = uv_layout(body, size)
    onehot = np.eye(5)[gt["garments"][0]]
    labels = rasterise_vertex_values(layout, onehot).argmax(axis=2)
    labels[~layout.chart] = -1
    tex = np.asarray(Image.open(scene_dir / "gt" / "subject_000" / "canonical.png").convert("RGB"))
    tex = cv2.resize(tex, (size, size), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    return labels, tex


def _spill(texture: np.ndarray, seen: np.ndarray, labels: np.ndarray, gt_tex: np.ndarray,
           seed: int = 0) -> tuple[float, float]:  # fmt: skip
    """(spill of ``texture`` over ``seen`` texels, the classifier's floor on the GT texture)."""
    from sklearn.neighbors import KNeighborsClassifier

    chart = labels >= 0
    rng = np.random.default_rng(seed)
    idx = np.flatnonzero(chart.ravel())
    train = rng.choice(idx, min(20000, idx.size), replace=False)
    flat_gt = gt_tex.reshape(-1, 3)
    clf = KNeighborsClassifier(5).fit(to_lab(flat_gt[train]), labels.ravel()[train])
    sel = np.flatnonzero((seen & chart).ravel())
    ours = texture.reshape(-1, 3)[sel].astype(np.float64)
    gain = (ours * flat_gt[sel]).sum(axis=0) / np.maximum((ours * ours).sum(axis=0), 1e-9)
    pred = clf.predict(to_lab(np.clip(ours * gain, 0, 1)))
    floor = clf.predict(to_lab(flat_gt[sel]))
    truth = labels.ravel()[sel]
    return float((pred != truth).mean()), float((floor != truth).mean())


def _ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    x = torch.as_tensor(a).permute(2, 0, 1)[None].float()
    y = torch.as_tensor(b).permute(2, 0, 1)[None].float()
    m = torch.as_tensor(mask, dtype=torch.float32)[None, None]
    s = ssim_map(x, y, mask=m)[0].mean(0).numpy()
    return float(s[mask].mean())


def run_scene(scene_dir: Path, args, settings: dict[str, TextureSettings]) -> dict[str, object]:
    scene = read_synth_scene(scene_dir)
    gt = scene.ground_truth
    body = load_body_model("anny")
    n = len(gt.poses)
    shape = torch.zeros(n, body.shape_dim)
    shape[:, :6] = torch.as_tensor(gt.shapes[gt.subject_of_frame][:, :6], dtype=torch.float32)
    poses = _perturb(gt.poses, args.pose_noise, args.jitter, args.noise_seed)
    with torch.no_grad():
        vertices = body(shape=shape, pose=torch.as_tensor(poses, dtype=torch.float32),
                        translation=torch.as_tensor(gt.translations, dtype=torch.float32),
                        ).vertices.numpy()  # fmt: skip
    faces, uv, face_uv = body.faces.numpy(), body.uv.numpy(), body.face_uv.numpy()
    images, masks = scene.frames.images, scene.observations.masks
    key = np.unique(np.linspace(0, n - 1, args.keyframes).round().astype(int))
    held = np.setdiff1d(np.arange(n), key)[::4]
    sh = estimate_sh(vertices[key[::4]], faces, images[key[::4]], masks[key[::4]], scene.camera)
    labels, gt_tex = _labels_and_texture(scene_dir, body, args.size)
    frags = {int(i): rasterize(vertices[i], faces, scene.camera) for i in held}
    out: dict[str, object] = {"scene": scene_dir.name, "keyframes": len(key), "held": len(held)}
    for name, st in settings.items():
        start = time.perf_counter()
        tex = build_texture(vertices[key], faces, uv, face_uv, images[key], masks[key],
                            scene.camera, sh, st)  # fmt: skip
        seconds = time.perf_counter() - start
        p, s = [], []
        for i in held:
            fr = frags[int(i)]
            img = render_textured(vertices[i], faces, fr, uv, face_uv,
                                  torch.from_numpy(tex.as_float()), sh=sh).numpy()  # fmt: skip
            img = np.clip(img, 0.0, 1.0)
            truth = images[i].astype(np.float32) / 255.0
            both = fr.mask.numpy() & masks[i]
            p.append(psnr(img, truth, both))
            s.append(_ssim(img, truth, both))
        spill, floor = _spill(tex.as_float(), tex.coverage, labels, gt_tex)
        out[name] = {"psnr": float(np.mean(p)), "ssim": float(np.mean(s)), "spill": spill,
                     "floor": floor, "seconds": seconds}  # fmt: skip
        if args.out:
            Image.fromarray(tex.image).save(args.out / f"{scene_dir.name}_{name}.png")
        print(f"  {scene_dir.name:28s} {name:9s} PSNR {np.mean(p):5.2f} dB  SSIM {np.mean(s):.4f}"
              f"  spill {100 * spill:5.2f} % (floor {100 * floor:4.2f} %)  {seconds:5.1f} s",
              flush=True)  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=Path, default=Path("bench_scenes"))
    parser.add_argument("--suite", action="store_true", help="the suite's clothed subjects")
    parser.add_argument("--seeds", type=int, nargs="*", default=[])
    parser.add_argument("--clothing", default="tshirt-shorts")
    parser.add_argument("--keyframes", type=int, default=30)
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--pose-noise", type=float, default=0.0, help="degrees RMS per joint")
    parser.add_argument("--jitter", type=float, default=0.0,
                        help="degrees RMS per joint, drawn per frame")  # fmt: skip
    parser.add_argument("--noise-seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[],
                        help="graphcut settings as name=value (e.g. w_gmm=0.1)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(2)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    subjects: list[BenchSubject] = []
    if args.suite:
        subjects += [s for s in FULL_SUBJECTS if s.category == "clothed"]
    for seed in args.seeds:
        subjects.append(BenchSubject(name=f"tune-{args.clothing}-s{seed}", category="clothed",
                                     seed=seed, clothing=args.clothing))  # fmt: skip
    base = TextureSettings(size=args.size)
    gc = base.graphcut
    for item in args.set:
        key, value = item.split("=")
        gc = replace(gc, **{key: type(getattr(gc, key))(value)})
    settings = {"median": base, "graphcut": replace(base, method="graphcut", graphcut=gc)}
    print(f"graphcut settings: {gc}")
    results = []
    for subject in subjects:
        folder = ensure_scene(subject, args.scenes, progress=False)
        results.append(run_scene(folder, args, settings))
    for name in settings:
        rows = [r[name] for r in results]
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        print(f"mean {name:9s} PSNR {mean['psnr']:5.2f} dB  SSIM {mean['ssim']:.4f}  spill "
              f"{100 * mean['spill']:5.2f} % (floor {100 * mean['floor']:4.2f} %)  "
              f"{mean['seconds']:5.1f} s")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps({"args": vars(args) | {"scenes": str(args.scenes),
                                         "out": str(args.out), "json": str(args.json)},
                                         "results": results}, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
