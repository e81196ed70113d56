"""Tracking accuracy, ablations, smoothness and speed (Paper A, Table A.1 and Fig. A.4) on
``monoavatar synth walk`` / ``jog`` scenes, mediapipe perception on the rendered frames.

For each scene: the tracker with mediapipe's 3D landmarks (``default``: the fit layer's
defaults on the perception as it comes) and with our lifter's (``lifter``: what ``monoavatar
track`` does by default; ``--lifter FILE`` for other weights), each with the mean error of
its 3D limb landmarks; without the flow term, without the 2D keypoint term and without the 3D
landmarks; and the per-frame pose fitter run frame by frame without
temporal terms (window 1, no smoothness), the baseline of the smoothness figure; and oracles
with the scene's truth in place of parts of the observations: ``exact-3d`` (mediapipe's 2D
keypoints and masks, the true 3D landmarks), ``exact-2d`` (true 2D keypoints with the scene's
jitter and true masks, no 3D landmarks) and ``exact-2d-3d`` (both). Joint errors
over 14 joints after a similarity per frame (local) and one per sequence (global), the
acceleration error, and seconds per frame (perception included, from the cache's second run
excluded: the first variant pays for perception). Run::

    python benchmarks/bench_track.py SCENE [SCENE ...] [--variants default no-flow ...]
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import load_body_model
from monoavatar.core.landmarks import LIMB_LANDMARKS
from monoavatar.datasets.synth_scene import stated_height
from monoavatar.eval.joints import tracking_errors
from monoavatar.fit.pose import PoseSettings, fit_poses
from monoavatar.fit.tracking import TrackSettings, track_motion
from monoavatar.pipelines.stages import InputSettings, load_inputs
from monoavatar.pipelines.track import EVAL_JOINTS, TrackConfig, lifted

VARIANTS = ("default", "lifter", "no-flow", "no-keypoints", "no-world", "per-frame")
ORACLES = ("exact-3d", "exact-2d", "exact-2d-3d")


def _oracle_observations(scene: Path, obs, variant: str):  # type: ignore[no-untyped-def]
    """``obs`` (mediapipe's) with the scene's true 3D landmarks (camera axes, metres about the
    hips' midpoint, confidence 1) and, for the ``exact-2d`` variants, its true 2D keypoints
    and masks; the flow stays mediapipe's run's (DIS on the frames)."""
    camera = obs.camera
    truth = np.load(scene / "keypoints.npz")["keypoints_3d"][obs.frame_indices]
    cam = truth @ np.asarray(camera.R).T + np.asarray(camera.t)
    rel = cam - 0.5 * (cam[:, 23] + cam[:, 24])[:, None]
    world = np.concatenate([rel, np.ones((*rel.shape[:2], 1))], -1).astype(np.float32)
    if variant == "exact-3d":
        return replace(obs, world_keypoints=world)
    exact = load_inputs(scene, InputSettings(frames=100_000, perception="ground-truth"))
    return replace(exact.observations, flow=obs.flow,
                   world_keypoints=world if variant == "exact-2d-3d" else None)


def landmark_errors(world: np.ndarray, truth_rel: np.ndarray) -> dict[str, float]:
    """Mean 3D error (mm) of the limb landmarks about the hips, after the best scale per frame
    and after a similarity per frame; ``world`` (N, 33, 4) hip-ray frame, ``truth_rel``
    (N, 33, 3) the truth about the hips in the same axes."""
    from monoavatar.eval.alignment import align_similarity

    scaled, similar = [], []
    limbs = list(LIMB_LANDMARKS)
    for w, t in zip(world[:, limbs, :3], truth_rel[:, limbs], strict=True):
        if not np.isfinite(w).all():
            continue
        s = float((w * t).sum() / max((w * w).sum(), 1e-12))
        scaled.append(np.linalg.norm(s * w - t, axis=-1).mean())
        a = align_similarity(w, t)
        similar.append(np.linalg.norm(a.scale * w @ a.rotation.T + a.translation - t,
                                      axis=-1).mean())  # fmt: skip
    return {"landmarks_scaled_mm": 1000 * float(np.mean(scaled)),
            "landmarks_similarity_mm": 1000 * float(np.mean(similar))}


def _truth_landmarks(scene: Path, obs) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(N, 33, 3) the scene's true landmarks about the hips, in each frame's hip-ray frame."""
    from monoavatar.learn.lifter import hip_ray_targets

    camera = obs.camera
    truth = np.load(scene / "keypoints.npz")["keypoints_3d"][obs.frame_indices]
    cam = truth @ np.asarray(camera.R).T + np.asarray(camera.t)
    return hip_ray_targets(torch.as_tensor(cam)).numpy()


def _joints_camera(body, shape, poses, trans, camera) -> np.ndarray:  # type: ignore[no-untyped-def]
    n = len(poses)
    with torch.no_grad():
        out = body(shape=torch.as_tensor(shape, dtype=body.dtype)[None].expand(n, -1),
                   pose=torch.as_tensor(poses, dtype=body.dtype),
                   translation=torch.as_tensor(trans, dtype=body.dtype))  # fmt: skip
    return out.joints.double().numpy() @ np.asarray(camera.R).T + np.asarray(camera.t)


def _overrides(pairs: list[str]) -> dict[str, object]:
    """``NAME=VALUE`` strings → TrackSettings fields (``pose.NAME``: its PoseSettings' fields),
    each VALUE parsed as its field's type; the pose fields come back under ``"pose"`` as a dict."""
    out: dict[str, object] = {}
    pose: dict[str, object] = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        target, defaults = (pose, PoseSettings()) if name.startswith("pose.") else (
            out, TrackSettings())  # fmt: skip
        name = name.removeprefix("pose.")
        if not hasattr(defaults, name) or name == "pose":
            raise SystemExit(f"--set: {type(defaults).__name__} has no field {name!r}")
        kind = type(getattr(defaults, name))
        target[name] = (value.lower() in ("1", "true", "yes")) if kind is bool else kind(value)
    if pose:
        out["pose"] = pose
    return out


def run(scene: Path, variants: tuple[str, ...], lifter: Path | None = None,
        world_weight: float | None = None,
        overrides: dict[str, object] | None = None) -> list[dict]:  # fmt: skip
    t0 = time.perf_counter()
    settings = replace(TrackConfig().input, perception="mediapipe")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        inputs = load_inputs(scene, settings)
    perception_s = time.perf_counter() - t0
    obs = inputs.observations
    info = json.loads((scene / "scene.json").read_text())
    height = stated_height(info)
    truth = np.load(scene / "gt" / "params.npz")["joints_camera"][obs.frame_indices]
    body = load_body_model("anny")
    sel = [body.joint_index(j) for j in EVAL_JOINTS]
    pose = PoseSettings(height=height)
    rows = []
    truth_rel = _truth_landmarks(scene, obs)
    for variant in variants:
        t0 = time.perf_counter()
        extra: dict[str, float] = {}
        if variant in ("default", "lifter"):
            if variant == "lifter":
                obs_v = lifted(obs, TrackConfig(lifter_weights=None if lifter is None
                                                else str(lifter),
                                                track=TrackSettings(pose=pose)))  # fmt: skip
            else:
                obs_v = obs
            if obs_v.world_keypoints is not None:
                extra = landmark_errors(obs_v.world_keypoints, truth_rel)
            extra_settings = dict(overrides or {})
            pose_v = replace(pose, **extra_settings.pop("pose", {}))  # type: ignore[arg-type]
            ts = replace(TrackSettings(pose=pose_v), **extra_settings)
            if world_weight is not None:
                ts = replace(ts, world_weight=world_weight)
            motion = track_motion(body, obs_v, ts)
            shape, poses, trans = motion.shape, motion.poses, motion.translations
        elif variant in ORACLES:
            motion = track_motion(body, _oracle_observations(scene, obs, variant),
                                  TrackSettings(pose=pose))  # fmt: skip
            shape, poses, trans = motion.shape, motion.poses, motion.translations
        elif variant == "per-frame":
            track = fit_poses(body, obs, replace(pose, window=1, smooth_weight=0.0))
            shape, poses, trans = track.shape, track.poses, track.translations
        else:
            ts = TrackSettings(pose=pose, flow=variant != "no-flow",
                               keypoints=variant != "no-keypoints", world=variant != "no-world")
            motion = track_motion(body, obs, ts)
            shape, poses, trans = motion.shape, motion.poses, motion.translations
        seconds = time.perf_counter() - t0
        pred = _joints_camera(body, shape, poses, trans, obs.camera)[:, sel]
        errors = tracking_errors(pred, truth[:, sel])
        rows.append({"scene": scene.name, "kind": info["config"]["kind"], "variant": variant,
                     **{k: round(v, 1) for k, v in (errors | extra).items()},
                     "s_per_frame": round((seconds + perception_s) / len(obs), 3),
                     "perception_s_per_frame": round(perception_s / len(obs), 3)})  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS),
                        choices=VARIANTS + ORACLES)  # fmt: skip
    parser.add_argument("-o", "--output", type=Path, default=None, help="a .json of the rows")
    parser.add_argument("--lifter", type=Path, default=None,
                        help="lifter weights (default: the shipped ones)")
    parser.add_argument("--world-weight", type=float, default=None,
                        help="weight of the 3D landmark term of the default and lifter "
                        "variants (default: TrackSettings')")  # fmt: skip
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                        help="TrackSettings fields for the default and lifter variants "
                        "(pose.NAME: its PoseSettings'), e.g. --set hips_weight=0.1 "
                        "hips=false pose.silhouette_points=600")  # fmt: skip
    args = parser.parse_args()
    rows = [r for scene in args.scenes
            for r in run(scene, tuple(args.variants), args.lifter, args.world_weight,
                         _overrides(args.set))]
    print("| scene | variant | local mm | global mm | accel mm/frame² | s/frame |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} ({r['kind']}) | {r['variant']} | {r['local_mm']} | "
              f"{r['global_mm']} | {r['acceleration_mm_per_frame2']} | {r['s_per_frame']} |")
    if args.output:
        args.output.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
