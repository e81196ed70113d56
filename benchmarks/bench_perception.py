"""Perception speed on 540×540 frames: mask + body landmarks + face per frame, and optical flow
per frame pair.

Frames: the astronaut photo shipped with scikit-image (a dev dependency), resized to 540×540
and shifted by a few pixels per frame, as a camera pan would. Run::

    python benchmarks/bench_perception.py [--frames 20] [--deepflow]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import cv2
import numpy as np

T = TypeVar("T")


def make_frames(n: int, size: int = 540) -> np.ndarray:
    """(n, size, size, 3) uint8 frames of a real photo panning by 2 px per frame."""
    from skimage import data

    photo = cv2.resize(data.astronaut(), (size, size), interpolation=cv2.INTER_AREA)
    frames = []
    for k in range(n):
        M = np.array([[1, 0, 2.0 * k - n], [0, 1, 0.5 * k]], dtype=np.float64)
        frames.append(cv2.warpAffine(photo, M, (size, size), borderMode=cv2.BORDER_REFLECT))
    return np.stack(frames)


def _per_call(fn: Callable[[T], object], items: Sequence[T]) -> float:
    fn(items[0])  # warm-up (graph initialisation)
    start = time.perf_counter()
    for item in items:
        fn(item)
    return (time.perf_counter() - start) / len(items)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--deepflow", action="store_true", help="also time DeepFlow (slow)")
    args = parser.parse_args()

    from monoavatar.io import Frames
    from monoavatar.perception import (
        DeepFlow,
        DISFlow,
        PerceptionSettings,
        default_detectors,
        detect_face,
        perceive,
    )

    images = make_frames(args.frames)
    n = len(images)
    print(f"{n} frames of {images.shape[2]}x{images.shape[1]} px, cv2 threads "
          f"{cv2.getNumThreads()}")

    with default_detectors() as dets:
        assert dets.pose is not None and dets.face is not None
        pose, face = dets.pose, dets.face
        t_pose = _per_call(pose.detect, list(images))
        keypoints = [r.keypoints if (r := pose.detect(im)) is not None else None for im in images]
        t_face = _per_call(lambda i: detect_face(images[i], face, keypoints[i]), list(range(n)))
        frames = Frames.from_images(images, fps=30.0)
        perceive(frames.subset([0]), detectors=dets, use_cache=False)  # warm-up
        start = time.perf_counter()
        perceive(frames, detectors=dets, use_cache=False)
        t_all = (time.perf_counter() - start) / n
        with tempfile.TemporaryDirectory() as cache:
            perceive(frames, detectors=dets, cache_dir=cache)
            start = time.perf_counter()
            perceive(frames, detectors=dets, cache_dir=cache)
            t_cached = (time.perf_counter() - start) / n
        settings = PerceptionSettings(grabcut=False)
        start = time.perf_counter()
        perceive(frames, settings=settings, detectors=dets, use_cache=False)
        t_raw = (time.perf_counter() - start) / n

    pairs = list(zip(images[:-1], images[1:], strict=True))
    dis = DISFlow("medium")
    t_dis = _per_call(lambda p: dis.estimate(*p), pairs)

    print(f"pose landmarks + mask (mediapipe)        {1000 * t_pose:7.1f} ms/frame")
    print(f"face mesh on the head crop               {1000 * t_face:7.1f} ms/frame")
    print(f"perceive(): mask + landmarks + face      {1000 * t_all:7.1f} ms/frame")
    print(f"perceive() without GrabCut (masks raw)   {1000 * t_raw:7.1f} ms/frame")
    print(f"perceive() from the cache                {1000 * t_cached:7.1f} ms/frame")
    print(f"optical flow, DIS medium                 {1000 * t_dis:7.1f} ms/pair")
    if args.deepflow:
        deep = DeepFlow()
        t_deep = _per_call(lambda p: deep.estimate(*p), pairs[:3])
        print(f"optical flow, DeepFlow                   {1000 * t_deep:7.1f} ms/pair")


if __name__ == "__main__":
    main()
