"""Perception accuracy on synthetic turn-around frames: person-mask IoU, 2D keypoint error as a
fraction of the person's height, left/right swaps, and time per frame.

Ground truth comes from a ``monoavatar synth`` folder: exact masks and exactly projected
landmarks with visibility. Keypoint errors are taken over the COCO-17 landmarks that are visible
in the truth; the person's height is the number of rows the true mask spans
(:mod:`monoavatar.perception.accuracy`). A frame counts as left/right swapped for a body part
(head, arms, legs) when the detected landmarks fit the truth at least twice as well with that
part's left and right exchanged. Run::

    python benchmarks/perception_accuracy.py SCENE_FOLDER [--json out.json]
    python benchmarks/perception_accuracy.py --frames 24 --size 384 --seed 0   # synthesised

Without a folder a turn-around is synthesised into a temporary folder first. Targets (issue 4):
median IoU >= 0.90 and median keypoint error <= 5 % of the height.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

IOU_TARGET = 0.90
KEYPOINT_TARGET_PCT = 5.0


def synthesise(folder: Path, frames: int, size: int, seed: int) -> Path:
    """Write a turn-around of ``frames`` frames of ``size`` px into ``folder``/scene."""
    from monoavatar.synth.scene import SynthConfig, generate

    out = folder / "scene"
    config = SynthConfig(kind="turnaround", frames=frames, seed=seed, width=size, height=size,
                         texture_size=512, posed_every=max(frames, 1))  # fmt: skip
    generate(out, config, progress=False)
    return out


def evaluate(scene_folder: Path, settings: Any) -> tuple[Any, float, list[str], Any]:
    """Perceive every frame of a synth scene (no cache) and compare with its ground truth.

    Returns the :class:`PerceptionAccuracy`, seconds per frame of :func:`perceive` (detectors
    made and warmed up beforehand), the warnings perception gave, and the Observations.
    """
    from monoavatar.datasets.synth_scene import read_synth_scene
    from monoavatar.perception import default_detectors, perceive
    from monoavatar.perception.accuracy import perception_accuracy

    scene = read_synth_scene(scene_folder, keypoints="exact")
    frames = scene.frames
    with default_detectors(settings) as dets, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        perceive(frames.subset([0]), scene.camera, settings, detectors=dets, use_cache=False)
        caught.clear()
        start = time.perf_counter()
        obs = perceive(frames, scene.camera, settings, detectors=dets, use_cache=False)
        seconds = (time.perf_counter() - start) / len(frames)
    gt = scene.ground_truth
    accuracy = perception_accuracy(obs, gt.masks, gt.keypoints)
    return accuracy, seconds, [str(w.message) for w in caught], obs


def report(
    name: str, acc: Any, seconds: float, messages: list[str], faces: int | None = None
) -> dict[str, Any]:
    """Print the figures and return them as a JSON-able dict (``faces``: frames with face
    landmarks, when known)."""
    s = acc.summary()
    n = int(s["frames"])
    face_text = "" if faces is None else f", face landmarks in {faces}"
    print(f"\n== {name}: {n} frames, person found in {int(s['detected'])}{face_text}, "
          f"height {s['height_px_median']:.0f} px (median)")  # fmt: skip
    for message in messages:
        print(f"   warning: {message}")
    iou_ok = "ok" if s["iou_median"] >= IOU_TARGET else "MISSED"
    kp_ok = "ok" if s["keypoint_error_pct_median"] <= KEYPOINT_TARGET_PCT else "MISSED"
    print(f"mask IoU        median {s['iou_median']:.4f}  mean {s['iou_mean']:.4f}  "
          f"min {s['iou_min']:.4f}   (target >= {IOU_TARGET:.2f}: {iou_ok})")
    print(f"keypoint error  median {s['keypoint_error_px_median']:.2f} px = "
          f"{s['keypoint_error_pct_median']:.2f} % of height, mean "
          f"{s['keypoint_error_pct_mean']:.2f} %, p90 {s['keypoint_error_pct_p90']:.2f} %   "
          f"(target <= {KEYPOINT_TARGET_PCT:.0f} %: {kp_ok})")
    print(f"                occluded landmarks included: median "
          f"{s['keypoint_error_pct_median_all']:.2f} %")
    groups = ", ".join(f"{g} {s[f'swap_pct_{g}']:.1f} %" for g in acc.swap_groups)
    print(f"left/right swapped frames: any {s['swap_pct_any']:.1f} % ({groups})")
    swapped_frames = np.flatnonzero(acc.swapped.any(axis=1)).tolist()
    if swapped_frames:
        print(f"   swapped in frames {swapped_frames}")
    print(f"speed           {1000.0 * seconds:.1f} ms/frame (perceive: mask, landmarks, face)")
    print("per joint (visible in the truth):   count   median px   median %   p90 %")
    rel = acc.relative_error
    per_joint = {}
    for j, joint in enumerate(acc.joint_names):
        ok = np.isfinite(acc.keypoint_error[:, j]) & acc.visible[:, j]
        if not ok.any():
            print(f"  {joint:16s} {0:20d}")
            continue
        px, pct = acc.keypoint_error[ok, j], 100.0 * rel[ok, j]
        per_joint[joint] = {"count": int(ok.sum()), "median_px": float(np.median(px)),
                            "median_pct": float(np.median(pct)),
                            "p90_pct": float(np.percentile(pct, 90))}  # fmt: skip
        print(f"  {joint:16s} {ok.sum():20d} {np.median(px):11.2f} {np.median(pct):10.2f} "
              f"{np.percentile(pct, 90):7.2f}")
    return {**s, "ms_per_frame": 1000.0 * seconds, "per_joint": per_joint,
            "swapped_frames": swapped_frames, "warnings": messages}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", type=Path, help="monoavatar synth folders")
    parser.add_argument("--frames", type=int, default=24, help="frames to synthesise")
    parser.add_argument("--size", type=int, default=384, help="synthesised image side, px")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthesised scene")
    parser.add_argument("--segmenter", choices=("pose", "selfie"), default="pose")
    parser.add_argument("--mask-threshold", type=float, default=None)
    parser.add_argument("--temporal-sigma", type=float, default=None)
    parser.add_argument("--no-grabcut", action="store_true",
                        help="masks without the GrabCut refinement of their boundary")
    parser.add_argument("--no-face", action="store_true", help="skip face landmarks")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    args = parser.parse_args()

    from monoavatar.perception import PerceptionSettings

    defaults = PerceptionSettings()
    settings = PerceptionSettings(
        segmenter=args.segmenter,
        mask_threshold=args.mask_threshold or defaults.mask_threshold,
        temporal_sigma=(
            defaults.temporal_sigma if args.temporal_sigma is None else args.temporal_sigma
        ),
        grabcut=not args.no_grabcut,
        face=not args.no_face,
    )
    print(f"settings: {settings}")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        scenes = list(args.scenes)
        if not scenes:
            start = time.perf_counter()
            scenes = [synthesise(Path(tmp), args.frames, args.size, args.seed)]
            print(f"synthesised {args.frames} frames of {args.size} px in "
                  f"{time.perf_counter() - start:.1f} s")  # fmt: skip
        for folder in scenes:
            acc, seconds, messages, obs = evaluate(folder, settings)
            faces = int(obs.face_found.sum()) if settings.face else None
            results[str(folder)] = report(str(folder), acc, seconds, messages, faces)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
