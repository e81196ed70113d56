"""Pose-fitting benchmark (issue 5): accuracy and speed on a synthetic turn-around.

    python benchmarks/bench_pose.py SCENE [--perception gt|mediapipe] [--frames N] [-o poses.npz]

Reports the mean per-frame joint error after per-frame Procrustes alignment (the 20 skeleton
joints of the fitted body against those of the ground-truth body), the silhouette IoU of the
fitted body against the exact ground-truth mask, left/right flips, and the time per frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from monoavatar.body import load_body_model
from monoavatar.datasets.synth_scene import read_synth_scene
from monoavatar.eval import pa_mpjpe
from monoavatar.fit.pose import PoseSettings, evaluate_fit, fit_poses


def flips(pred: np.ndarray, gt: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """(N,) True where, after Procrustes alignment of the frame, the left limbs of the fit lie
    closer to the ground truth's right limbs than to its left ones."""
    from monoavatar.eval.alignment import align_similarity

    pairs = [(names.index(n), names.index(n[:-1] + "r")) for n in names if n.endswith("_l")]
    out = np.zeros(len(pred), bool)
    for i in range(len(pred)):
        tf = align_similarity(pred[i], gt[i])
        p = tf.apply(pred[i])
        right = sum(np.linalg.norm(p[a] - gt[i][b]) for a, b in pairs)
        same = sum(np.linalg.norm(p[a] - gt[i][a]) for a, b in pairs)
        out[i] = right < same
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("scene")
    parser.add_argument("--perception", choices=("gt", "mediapipe"), default="gt")
    parser.add_argument("--frames", type=int, default=None)
    parser.add_argument("--height", action="store_true", help="give the true height")
    parser.add_argument("-o", "--output", default=None)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    frames = None
    scene = read_synth_scene(args.scene)
    if args.frames:
        frames = np.round(np.linspace(0, len(scene.frames) - 1, args.frames)).astype(int)
        scene = read_synth_scene(args.scene, frames=frames)
    obs = scene.observations
    if args.perception == "mediapipe":
        from monoavatar.perception import perceive

        obs = perceive(scene.frames, scene.camera)
    body = load_body_model("anny")
    gt_body = load_body_model("anny-local")
    gt = scene.ground_truth
    gt_out = gt.body_output(gt_body)
    height = None
    if args.height:
        rest, _ = gt_body.rest_shape(torch.as_tensor(gt.shapes[:1], dtype=gt_body.dtype))
        height = float(rest[0, :, 1].max() - rest[0, :, 1].min())
    start = time.perf_counter()
    track = fit_poses(body, obs, PoseSettings(height=height), progress=True)
    seconds = time.perf_counter() - start
    with torch.no_grad():
        out = body(shape=torch.as_tensor(track.shape, dtype=body.dtype)[None].expand(len(obs), -1),
                   pose=torch.as_tensor(track.poses, dtype=body.dtype),
                   translation=torch.as_tensor(track.translations, dtype=body.dtype))
    pred_j = out.joints.double().numpy()
    gt_j = gt_out.joints.double().numpy()
    err = [pa_mpjpe(pred_j[i], gt_j[i]) for i in range(len(obs))]
    flip = flips(pred_j, gt_j, body.joint_names)
    _, iou_gt = evaluate_fit(body, torch.as_tensor(track.shape), track.poses,
                             track.translations, scene.observations)  # fmt: skip
    print(f"frames {len(obs)}  perception {args.perception}")
    print(f"PA joint error mean {np.mean(err):.1f} mm  median {np.median(err):.1f}  "
          f"max {np.max(err):.1f}")
    print(f"IoU vs GT mask median {np.median(iou_gt):.3f}  min {np.min(iou_gt):.3f}")
    print(f"flips {int(flip.sum())} frames {np.flatnonzero(flip).tolist()[:20]}")
    print(f"failed {int(track.failed.sum())}")
    print(f"time {seconds:.1f} s = {seconds / len(obs):.2f} s/frame; {track.timings}")
    print(f"height {track.height:.3f} m (scale known: {track.scale_known})")
    worst = np.argsort(err)[-5:]
    print("worst frames", worst.tolist(), np.round(np.array(err)[worst], 1).tolist())
    if args.output:
        track.save(args.output)


if __name__ == "__main__":
    main()
