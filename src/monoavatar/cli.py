"""The ``monoavatar`` command line: one sub-command per capability.

Each verb is a pair: ``_add_VERB`` declares its options and ``_run_VERB`` runs it. Options
that set a settings dataclass take their default from that dataclass (:func:`_default`), so a
default is stated once. Every :class:`~monoavatar.core.errors.MonoavatarError` (and a failed
read or write) becomes a one-line message and exit code 2, in :func:`main` alone. To add a
verb: write the pair and add it to :data:`VERBS`. A verb's options are built only when that
verb runs, so that ``monoavatar --help`` does not import the pipelines.
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import MISSING, fields, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monoavatar import __version__
from monoavatar.core.errors import InputWarning, MonoavatarError

if TYPE_CHECKING:
    from monoavatar.body import BodyModel
    from monoavatar.io.avatar_folder import Report
    from monoavatar.pipelines.fast import FastConfig, FastResult
    from monoavatar.pipelines.reconstruct import ReconstructConfig, ReconstructResult
    from monoavatar.pipelines.stages import Inputs


class CliError(MonoavatarError):
    """A user-facing error of the command line: printed without a traceback, exit code 2."""


def _default(cls: type, name: str) -> Any:
    """The default of field ``name`` of the dataclass ``cls``."""
    for f in fields(cls):
        if f.name == name:
            if f.default is not MISSING:
                return f.default
            if f.default_factory is not MISSING:
                return f.default_factory()
    raise KeyError(f"{cls.__name__} has no field {name!r} with a default")


def _option(p: argparse.ArgumentParser, flag: str, cls: type, name: str, help: str,
            **kwargs: Any) -> None:  # fmt: skip
    """An option whose default is field ``name`` of ``cls``; the help shows it."""
    p.add_argument(flag, default=_default(cls, name), help=f"{help} (default: %(default)s)",
                   **kwargs)  # fmt: skip


# -- synth, body ------------------------------------------------------------------------------


def _add_synth(p: argparse.ArgumentParser) -> None:
    from monoavatar.synth.options import (
        BACKGROUNDS,
        CAPTURES,
        CLOTHING,
        KINDS,
        NOISE_LEVELS,
        VARIETIES,
    )
    from monoavatar.synth.scene import SynthConfig

    p.description = ("Render a person with known 3D shape, clothing, texture and motion through "
                     "a fixed camera, and write frames, a video, exact masks, 2D keypoints, the "
                     "camera, ground-truth meshes and parameters, and a contact sheet. The same "
                     "seed gives the same scene.")  # fmt: skip
    p.add_argument("kind", choices=KINDS, help="turnaround: one turn in an A-pose; motion: "
                   "walking, waving, jogging in place; walk, jog: along an oblique path; "
                   "photo: single images, one person each")
    p.add_argument("-o", "--output", required=True, type=Path, help="new or empty folder")
    _option(p, "--frames", SynthConfig, "frames", "number of frames", type=int)
    _option(p, "--seed", SynthConfig, "seed", "random seed", type=int)
    p.add_argument("--size", type=int, nargs=2, metavar=("W", "H"),
                   default=(_default(SynthConfig, "width"), _default(SynthConfig, "height")),
                   help="image size in pixels, even (default: %(default)s)")  # fmt: skip
    _option(p, "--clothing", SynthConfig, "clothing", "garment set (None: drawn from the seed)",
            choices=CLOTHING)  # fmt: skip
    _option(p, "--noise", SynthConfig, "noise", "image noise, blur, JPEG and keypoint jitter",
            choices=list(NOISE_LEVELS))  # fmt: skip
    _option(p, "--background", SynthConfig, "background", "background (None: drawn from the "
            "seed)", choices=BACKGROUNDS)  # fmt: skip
    _option(p, "--texture-size", SynthConfig, "texture_size", "texture pixels", type=int)
    _option(p, "--posed-every", SynthConfig, "posed_every",
            "write the posed ground-truth mesh every N frames", type=int)  # fmt: skip
    _option(p, "--capture", SynthConfig, "capture", "how it is filmed: studio (a level camera "
            "aimed at the person, one even turn) or phone (rolled and off-centre, an uneven "
            "turn, exposure drift, motion blur, a sun that casts shadows, a coarser H.264 "
            "video)",
            choices=list(CAPTURES))  # fmt: skip
    _option(p, "--variety", SynthConfig, "variety", "subjects drawn from the standard "
            "distribution or the wide one (heights 1.50-1.95 m, stronger local shape changes, "
            "garments 6-25 mm thick, hair styles, shoes 6-20 mm)",
            choices=list(VARIETIES))  # fmt: skip
    p.set_defaults(run=_run_synth)


def _run_synth(args: argparse.Namespace) -> int:
    from monoavatar.synth.scene import SynthConfig, generate

    config = SynthConfig(kind=args.kind, frames=args.frames, seed=args.seed, width=args.size[0],
                         height=args.size[1], clothing=args.clothing, noise=args.noise,
                         background=args.background, texture_size=args.texture_size,
                         posed_every=args.posed_every, capture=args.capture,
                         variety=args.variety)  # fmt: skip
    summary = generate(args.output, config)
    print(
        f"wrote {summary.frames} frames of {summary.subjects} subject(s) to {summary.folder} "
        f"in {summary.seconds:.1f} s\n"
        f"  preview: {summary.folder / 'preview' / 'contact_sheet.png'}\n"
        f"  description: {summary.folder / 'scene.json'}"
    )
    return 0


def _add_body(p: argparse.ArgumentParser) -> None:
    p.description = ("Pose the body model (Anny by default, or your SMPL file) and write it as "
                     "an OBJ with UVs and a preview PNG.")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--model", default="anny",
                   help="'anny' (default), 'anny-local', or a path to an SMPL .npz/.pkl")
    p.add_argument("--pose", choices=("rest", "wave", "walk"), default="wave",
                   help="(default: %(default)s)")  # fmt: skip
    p.set_defaults(run=_run_body)


def _run_body(args: argparse.Namespace) -> int:
    import numpy as np
    import torch
    from PIL import Image

    from monoavatar.body import load_body_model
    from monoavatar.core.camera import PinholeCamera
    from monoavatar.io.export_mesh import write_obj
    from monoavatar.render import rasterize, render_normals

    body = load_body_model(args.model)
    pose = body.zero_pose()
    names = body.joint_names
    if args.pose == "wave" and "shoulder_r" in names:
        pose[0, names.index("shoulder_r"), 2] = -1.5
        pose[0, names.index("elbow_r"), 2] = -1.0
    elif args.pose == "walk" and "hip_l" in names:
        pose[0, names.index("hip_l"), 0] = -0.4
        pose[0, names.index("knee_r"), 0] = 0.6
        pose[0, names.index("shoulder_l"), 0] = 0.4
    args.output.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        out = body(pose=pose)
    v = out.vertices[0].numpy()
    write_obj(args.output / "body.obj", v, body.faces.numpy(), body.uv.numpy(),
              body.face_uv.numpy())  # fmt: skip
    cam = PinholeCamera.look_at(np.array([0.0, 0.0, 3.0]), np.zeros(3), np.array([0, 1.0, 0]),
                                700, 540, 540)  # fmt: skip
    frags = rasterize(v, body.faces, cam)
    normals = render_normals(out.vertices[0], body.faces, frags)
    shade = (0.25 + 0.75 * normals[..., 2].clamp(0, 1)).numpy()
    image = np.where((frags.face_id >= 0).numpy(), shade, 1.0)
    Image.fromarray((image * 255).astype(np.uint8)).save(args.output / "preview.png")
    print(f"wrote {args.output / 'body.obj'} and {args.output / 'preview.png'} ({body.identity})")
    return 0


# -- the reconstruction's options -------------------------------------------------------------


def _add_input_options(p: argparse.ArgumentParser) -> None:
    from monoavatar.fit.pose import PoseSettings
    from monoavatar.pipelines.stages import PERCEPTION, InputSettings

    p.add_argument("input", type=Path, nargs="+", metavar="INPUT",
                   help="a video file (mp4, mov, avi, webm), a folder of images, several image "
                   "files (same size; taken in natural order of their names), a "
                   "People-Snapshot folder, or a folder written by 'monoavatar synth'")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output folder (created; existing result files are replaced)")  # fmt: skip
    _option(p, "--frames", InputSettings, "frames",
            "key-frames to use, spread evenly over the input", type=int)  # fmt: skip
    _option(p, "--height", PoseSettings, "height", "the person's height in metres, standing "
            "without shoes, e.g. 1.75; without it the result is up to scale (an average height "
            "is assumed)", type=float,
            metavar="M")  # fmt: skip
    _option(p, "--focal", InputSettings, "focal", "focal length in pixels (None: a 68 degree "
            "diagonal field of view, typical of phone cameras; a synth or People-Snapshot "
            "folder brings its own)", type=float, metavar="PX")  # fmt: skip
    _option(p, "--camera", InputSettings, "camera",
            "a camera.json with the intrinsics instead of --focal", metavar="JSON")
    _option(p, "--perception", InputSettings, "perception", "masks and keypoints: auto (a "
            "synth or People-Snapshot folder's own, else mediapipe), mediapipe, or "
            "ground-truth", choices=PERCEPTION)  # fmt: skip
    p.add_argument("--no-grabcut", action="store_true",
                   help="keep mediapipe's person masks as they are, without the GrabCut "
                   "refinement of their boundary (on by default)")  # fmt: skip
    _option(p, "--max-side", InputSettings, "max_side", "larger frames of a video or image "
            "folder are downscaled so that their longer side has this many pixels (0 keeps "
            "the source's size)", type=int, metavar="PX")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _config(args: argparse.Namespace, **options: Any) -> ReconstructConfig:
    """The :class:`ReconstructConfig` of the parsed options (those a verb lacks keep their
    defaults), with ``options`` replacing top-level fields."""
    from monoavatar.perception import PerceptionSettings
    from monoavatar.pipelines.reconstruct import ReconstructConfig
    from monoavatar.pipelines.stages import InputSettings

    base = ReconstructConfig()
    workers = getattr(args, "workers", base.flow.workers)
    if workers < 1:
        raise CliError(f"--workers must be at least 1, got {workers}")
    try:
        return ReconstructConfig(
            input=InputSettings(
                frames=args.frames, focal=args.focal, camera=args.camera,
                perception=args.perception, poses=getattr(args, "pose_source", "fit"),
                perception_settings=replace(PerceptionSettings(), grabcut=not args.no_grabcut),
                max_side=getattr(args, "max_side", _default(InputSettings, "max_side")) or None,
                workers=workers,
            ),
            device=getattr(args, "device", base.device),
            body_model=getattr(args, "model", base.body_model),
            refine_rounds=getattr(args, "refine_rounds", base.refine_rounds),
            flow_rounds=getattr(args, "flow_rounds", base.flow_rounds),
            progress=not args.quiet,
            pose=replace(base.pose, height=args.height),
            shape=replace(base.shape, fit_offsets=not getattr(args, "no_offsets", False),
                          w_face=getattr(args, "face_weight", base.shape.w_face),
                          workers=workers),
            texture=replace(base.texture, size=getattr(args, "texture_size", base.texture.size),
                            workers=workers,
                            method=getattr(args, "texture_method", base.texture.method)),
            flow=replace(base.flow, workers=workers),
        )  # fmt: skip
    except ValueError as exc:  # a settings dataclass refused a value
        raise CliError(str(exc)) from exc


def _add_reconstruct(p: argparse.ArgumentParser) -> None:
    from monoavatar.fit.shape import ShapeSettings
    from monoavatar.pipelines.fast import FAST_MAX_FRAMES, FastConfig
    from monoavatar.pipelines.reconstruct import ReconstructConfig
    from monoavatar.pipelines.stages import POSES
    from monoavatar.texture.backproject import METHODS, TextureSettings

    p.description = (
        "Reconstruct a textured, rigged avatar from a video of a person turning around in front "
        "of a static camera (dissertation Paper B): perception, pose fitting, consensus shape "
        "with per-vertex offsets, texture, and export to avatar.glb (skinned, textured glTF "
        "2.0), avatar.obj/.mtl + texture.png, params.npz, report.json and preview images. "
        "Stages that ran before on the same input and settings are reused from the cache "
        "($MONOAVATAR_CACHE, default ~/.cache/monoavatar). On a synth folder the surface error "
        "against its ground truth is added to report.json and printed.")
    _add_input_options(p)
    _option(p, "--texture-size", TextureSettings, "size", "texture side in texels", type=int,
            metavar="S")  # fmt: skip
    p.add_argument("--texture", dest="texture_method", choices=METHODS,
                   default=_default(TextureSettings, "method"),
                   help="how the key-frames' colours are merged: the median of the most "
                   "orthogonal views, or one view per texel chosen by semantic graph cuts "
                   "(Paper C) (default: %(default)s)")  # fmt: skip
    _option(p, "--device", ReconstructConfig, "device", "where to compute (every stage runs on "
            "the CPU)", choices=("cpu", "cuda"))  # fmt: skip
    p.add_argument("--poses", dest="pose_source", choices=POSES, default=POSES[0],
                   help="fit the poses, or take a synth folder's true poses (benchmarks of "
                   "the shape stage) (default: %(default)s)")  # fmt: skip
    p.add_argument("--no-offsets", action="store_true",
                   help="fit the body model's shape only, without per-vertex offsets "
                   "(the baseline of the benchmark)")  # fmt: skip
    _option(p, "--face-weight", ShapeSettings, "w_face", "weight of the face term (Paper C): "
            "the face-mesh landmarks detected in the key-frames pull the avatar's face onto "
            "their rays (0 turns it off; faces are found only where they are large enough, "
            "about 25 pixels between the eyes' outer corners)", type=float,
            metavar="W")  # fmt: skip
    _option(p, "--refine-rounds", ReconstructConfig, "refine_rounds", "rounds of pose "
            "re-fitting with the consensus shape by keypoints and silhouette, each followed by "
            "the shape again, before the texture", type=int, metavar="R")  # fmt: skip
    _option(p, "--flow-rounds", ReconstructConfig, "flow_rounds", "rounds of key-frame pose "
            "refinement by optical flow from the textured avatar to each frame and by the "
            "outline, each followed by the shape and the texture again (0 turns it off)",
            type=int, metavar="R")  # fmt: skip
    _option(p, "--workers", TextureSettings, "workers", "threads that refine the person "
            "masks while the detectors run, and match, fit and texture key-frames side by side "
            "in the shape, flow and texture stages (results vary by float rounding between "
            "runs, with any count)", type=int, metavar="N")  # fmt: skip
    _option(p, "--model", ReconstructConfig, "body_model",
            "body model: anny or a path to your SMPL .npz/.pkl")  # fmt: skip
    p.add_argument("--fast", action="store_true",
                   help="predict the shape and poses from 1-8 key-frames with the few-frame "
                   f"network (Paper D) instead of fitting them: seconds instead of minutes "
                   f"(--frames defaults to {FAST_MAX_FRAMES}; --poses, --no-offsets, --refine-"
                   "rounds, --flow-rounds and --model do not apply)")  # fmt: skip
    _option(p, "--weights", FastConfig, "weights", "with --fast: a few-frame network "
            "weights file (from 'monoavatar train fast'; default: the shipped weights)",
            metavar="FILE")  # fmt: skip
    _option(p, "--budget", FastConfig, "budget", "with --fast: seconds of top-down refinement "
            "of the network's prediction against the frames' silhouettes and keypoints (0: the "
            "prediction as it is)", type=float, metavar="S")  # fmt: skip
    p.set_defaults(run=_run_reconstruct)


def _with_ground_truth(result: ReconstructResult | FastResult, body: BodyModel) -> None:
    """For a synth input: the surface error against its ground truth, into report.json, and
    each vertex's, into ground_truth.npz (the heat map of ``monoavatar view``)."""
    from monoavatar.bench.ground_truth import ground_truth_error_map
    from monoavatar.core.files import atomic_write_npz
    from monoavatar.io.avatar_folder import GROUND_TRUTH_FILE

    truth = result.inputs.ground_truth
    if truth is None:
        return
    result.report.ground_truth, errors = ground_truth_error_map(body, result.shape, truth)
    atomic_write_npz(result.out_dir / GROUND_TRUTH_FILE, vertex_error_m=errors)
    result.report.write(result.out_dir / "report.json")


def _fast_config(args: argparse.Namespace) -> FastConfig:
    """The :class:`FastConfig` of ``reconstruct --fast``'s options (``--frames`` left at the
    full pipeline's default means the network's eight)."""
    from monoavatar.pipelines.fast import FAST_MAX_FRAMES, FastConfig
    from monoavatar.pipelines.stages import InputSettings
    from monoavatar.texture.backproject import TextureSettings

    base = _config(args)
    if args.pose_source != "fit":
        raise CliError("--poses ground-truth does not apply to --fast")
    frames = args.frames
    if frames == _default(InputSettings, "frames"):
        frames = FAST_MAX_FRAMES
    return FastConfig(input=replace(base.input, frames=frames), height=args.height,
                      budget=args.budget, weights=args.weights, device=args.device,
                      texture=replace(TextureSettings(), size=args.texture_size,
                                      method=args.texture_method, workers=args.workers),
                      progress=not args.quiet)  # fmt: skip


def _run_reconstruct(args: argparse.Namespace) -> int:
    from monoavatar.body import load_body_model
    from monoavatar.pipelines.fast import FastConfig, fast_reconstruct
    from monoavatar.pipelines.reconstruct import reconstruct

    if args.fast:
        fast = fast_reconstruct(args.input, args.output, _fast_config(args))
        _with_ground_truth(fast, load_body_model("anny"))
        _print_summary(fast.report, fast.out_dir)
        return 0
    if args.weights is not None:
        raise CliError("--weights applies to --fast only")
    if args.budget != _default(FastConfig, "budget"):
        raise CliError("--budget applies to --fast only")
    result = reconstruct(args.input, args.output, _config(args))
    _with_ground_truth(result, result.body)
    _print_summary(result.report, result.out_dir)
    return 0


def _print_summary(report: Report, out: Path) -> None:
    fit = report.fit
    print(f"avatar written to {out}/")
    print("  avatar.glb  avatar.obj  texture.png  params.npz  report.json  keyframes.jpg  preview/"
          + ("  ground_truth.npz" if report.ground_truth is not None else ""))
    print(f"  key-frames: {report.input.frames}  failed: {int(sum(fit.failed))}  "
          f"median silhouette IoU: {fit.median_silhouette_iou:.3f}")  # fmt: skip
    if fit.median_face_error is not None and fit.face_error is not None:
        found = sum(e is not None for e in fit.face_error)
        print(f"  face: the face-mesh landmarks lie {100 * fit.median_face_error:.1f} % of the eye "
              f"corners' distance from the avatar's face (median over {found} key-frame"
              f"{'s' if found != 1 else ''} with a face)")  # fmt: skip
    print(f"  height: {report.scale.height_m:.3f} m ({report.scale.note})")
    print("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in report.timings.items())
          + f"; total {report.seconds:.1f} s")  # fmt: skip
    if report.ground_truth is not None:
        gt = report.ground_truth
        print(f"  surface error against the ground truth: {gt.surface_error_mm:.2f} mm "
              f"after pose and scale alignment ({gt.surface_error_rigid_mm:.2f} mm "
              "after a similarity transform alone)")  # fmt: skip
        if gt.bone_angle_median_deg is not None:
            print(f"  rest pose against the ground truth's: bones {gt.bone_angle_median_deg:.1f}° "
                  f"off (median), {gt.bone_angle_max_deg:.1f}° at worst ({gt.bone_angle_worst})")
    for warning in report.warnings[:5]:
        print(f"  warning: {warning}")
    _print_view_line(out)


def _print_view_line(out: Path) -> None:
    print(f"look at it: monoavatar view {out}")


# -- track -------------------------------------------------------------------------------------


def _add_track(p: argparse.ArgumentParser) -> None:
    from monoavatar.fit.pose import PoseSettings
    from monoavatar.fit.tracking import TrackSettings
    from monoavatar.pipelines.stages import PERCEPTION, InputSettings
    from monoavatar.pipelines.track import LANDMARK_SOURCES, TrackConfig

    p.description = (
        "Track a person's 3D motion through a video with a static camera (dissertation Paper "
        "A): mediapipe masks and 2D landmarks, 3D landmarks lifted from them by a learned "
        "lifter, and optical flow per frame; the body (an avatar's, or a shape fitted on the "
        "first frames) posed frame by frame from a Kalman "
        "prediction to match the observed flow, silhouette and landmarks. Writes motion.npz "
        "(poses, translations, landmarks in the camera and an upright world frame), motion.bvh "
        "(Blender, Maya, Unity), motion.glb (the body animated), preview/overlay.mp4 and "
        "report.json into a new or empty folder. On a synth folder with ground-truth joints the "
        "joint errors of Table A.1 are added to report.json and printed.")
    p.add_argument("input", type=Path, help="a video file, a folder of images (in order), or a "
                   "folder written by 'monoavatar synth walk|jog|motion'")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output folder (new or empty)")  # fmt: skip
    _option(p, "--avatar", TrackConfig, "avatar", "a 'monoavatar reconstruct' folder whose "
            "avatar is tracked (None: a body shape is fitted on the first frames)",
            metavar="DIR")  # fmt: skip
    _option(p, "--height", PoseSettings, "height", "the person's height in metres, e.g. 1.75 "
            "(without it, and without --avatar, the motion is up to scale)", type=float,
            metavar="M")  # fmt: skip
    _option(p, "--focal", InputSettings, "focal", "focal length in pixels (None: a 68 degree "
            "diagonal field of view; a synth folder brings its own)", type=float,
            metavar="PX")  # fmt: skip
    _option(p, "--perception", InputSettings, "perception", "masks and landmarks: auto (a "
            "synth folder's own, else mediapipe), mediapipe, or ground-truth",
            choices=PERCEPTION)  # fmt: skip
    _option(p, "--fps", TrackConfig, "fps", "frame rate of the outputs (None: the input's)",
            type=float)  # fmt: skip
    p.add_argument("--frames", dest="frame_range", type=_frame_range, default=None,
                   metavar="A:B", help="track source frames A (inclusive) to B (exclusive), "
                   "0-based; either may be left out, e.g. 120: or :300 (default: all)")
    p.add_argument("--flow-method", choices=("dis", "deepflow"), default="dis",
                   help="optical flow: OpenCV's DIS (fast) or DeepFlow (slower, more accurate; "
                   "default: %(default)s)")  # fmt: skip
    p.add_argument("--grabcut", action=argparse.BooleanOptionalAction,
                   default=TrackConfig().input.perception_settings.grabcut,
                   help="refine mediapipe's person masks with GrabCut, as reconstruct does "
                   "(slower; the track hardly depends on it; default: %(default)s)")
    p.add_argument("--no-flow", action="store_true", help="without the flow term (Eq. A.1)")
    p.add_argument("--no-keypoints", action="store_true",
                   help="without the 2D keypoint term (flow, silhouette and 3D landmarks only)")
    p.add_argument("--no-world", action="store_true",
                   help="without the 3D landmark term")  # fmt: skip
    _option(p, "--landmarks-3d", TrackConfig, "landmarks_3d", "the 3D landmarks: 'lifter' "
            "(lifted from the 2D landmarks by our learned lifter) or 'detector' (mediapipe's "
            "world landmarks)", choices=LANDMARK_SOURCES)  # fmt: skip
    _option(p, "--lifter-weights", TrackConfig, "lifter_weights", "a lifter weights file "
            "(from 'monoavatar train lifter'; None: the shipped weights)",
            metavar="FILE")  # fmt: skip
    _option(p, "--flow-weight", TrackSettings, "flow_weight", "weight of the flow term",
            type=float)  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_track)


def _frame_range(text: str) -> tuple[int | None, int | None]:
    """``"A:B"`` → (A, B), either None when left out; A < B, both >= 0."""
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        first, stop = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (frame indices), got {text!r}") from None
    if (first is not None and first < 0) or (stop is not None and stop < 0):
        raise argparse.ArgumentTypeError(f"frame indices must be >= 0, got {text!r}")
    if first is not None and stop is not None and stop <= first:
        raise argparse.ArgumentTypeError(f"B must be after A, got {text!r}")
    return first, stop


def _run_track(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from monoavatar.pipelines.track import TrackConfig, track

    config = TrackConfig()
    pose = replace(config.track.pose, height=args.height)
    config.track = replace(config.track, pose=pose, flow=not args.no_flow,
                           keypoints=not args.no_keypoints, world=not args.no_world,
                           flow_weight=args.flow_weight)  # fmt: skip
    perception = replace(config.input.perception_settings, grabcut=args.grabcut,
                         flow=None if args.no_flow else args.flow_method)  # fmt: skip
    first, stop = args.frame_range if args.frame_range is not None else (None, None)
    config.input = replace(config.input, focal=args.focal, perception=args.perception,
                           perception_settings=perception, first=first, stop=stop)  # fmt: skip
    config.avatar = None if args.avatar is None else str(args.avatar)
    config.landmarks_3d = args.landmarks_3d
    config.lifter_weights = None if args.lifter_weights is None else str(args.lifter_weights)
    config.fps = args.fps
    config.progress = not args.quiet
    result = track(args.input, args.output, config)
    report = result.report
    print(f"motion written to {result.folder}/")
    print("  motion.npz  motion.bvh  motion.glb  preview/overlay.mp4  report.json  keyframes.jpg")
    print(f"  frames: {report['input']['frames']}  failed: {report['frames_failed']}  "
          f"re-initialised: {report['frames_reinitialised']}  "
          f"time: {report['seconds']:.1f} s ({report['seconds_per_frame']:.2f} s per frame)")
    if "ground_truth" in report:
        gt = report["ground_truth"]
        print(f"  joint error against the ground truth: {gt['local_mm']:.1f} mm local, "
              f"{gt['global_mm']:.1f} mm global; acceleration error "
              f"{gt['acceleration_mm_per_frame2']:.1f} mm/frame^2")  # fmt: skip
    for warning in report["warnings"][:5]:
        print(f"  warning: {warning}")
    _print_view_line(result.folder)
    return 0


# -- fit-poses, fit-shape ---------------------------------------------------------------------


def _inputs_and_body(args: argparse.Namespace) -> tuple[ReconstructConfig, Inputs, BodyModel]:
    """The checked configuration, the read and perceived inputs, and the body model of a verb
    with the input options (the output folder created)."""
    from monoavatar.body import load_body_model
    from monoavatar.pipelines.stages import load_inputs

    config = _config(args)
    config.validate()
    args.output.mkdir(parents=True, exist_ok=True)  # an unwritable output fails before the work
    inputs = load_inputs(args.input, config.input, progress=config.progress)
    return config, inputs, load_body_model(config.body_model)


def _add_fit_poses(p: argparse.ArgumentParser) -> None:
    p.description = ("Fit one body shape and a 3D pose per key-frame to the person masks and 2D "
                     "keypoints of a video. Writes OUT/poses.npz (shape, poses (axis-angle "
                     "radians), translations (metres), camera, per-frame keypoint error, "
                     "silhouette IoU and failure flags).")  # fmt: skip
    _add_input_options(p)
    p.set_defaults(run=_run_fit_poses)


def _run_fit_poses(args: argparse.Namespace) -> int:
    import numpy as np

    from monoavatar.pipelines.stages import pose_stage

    config, inputs, body = _inputs_and_body(args)
    track = pose_stage(body, inputs, config.pose, progress=config.progress)
    track.save(args.output / "poses.npz")
    good = ~track.failed
    print(f"wrote {args.output / 'poses.npz'}: {len(track.poses)} frames, "
          f"{int((~good).sum())} failed, median keypoint error "
          f"{np.nanmedian(track.keypoint_error):.1f} px, median silhouette IoU "
          f"{np.median(track.silhouette_iou):.3f}, {track.seconds:.1f} s; height "
          f"{track.height:.2f} m ({'given' if track.scale_known else 'up to scale'})")  # fmt: skip
    return 0


def _add_fit_shape(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Fit the consensus shape of the person in a video: silhouette rays of every key-frame "
        "unposed into the canonical pose, the body model's shape and per-vertex offsets fitted "
        "to them, alternating with re-fits of the poses. Poses come from 'monoavatar "
        "fit-poses' (--poses) or are fitted (and cached) first. Writes OUT/shape.npz (shape, "
        "offsets (metres), canonical vertices and faces, the frames used, their translation "
        "corrections, poses and translations) and OUT/canonical.obj; on a synth folder prints "
        "the surface error against the ground truth.")
    _add_input_options(p)
    p.add_argument("--poses", type=Path, default=None, metavar="NPZ",
                   help="a poses.npz from 'monoavatar fit-poses' on the same input and "
                   "--frames (default: fit the poses here)")  # fmt: skip
    p.add_argument("--no-offsets", action="store_true",
                   help="the body model's shape only (the shape-only baseline)")
    p.add_argument("--refine-rounds", type=int, default=1, metavar="R",
                   help="rounds of pose re-fitting with the consensus shape (default: "
                   "%(default)s; reconstruct's default is 0, as its flow rounds re-fit the "
                   "poses)")  # fmt: skip
    p.set_defaults(run=_run_fit_shape)


def _run_fit_shape(args: argparse.Namespace) -> int:
    import numpy as np

    from monoavatar.bench.ground_truth import ground_truth_error
    from monoavatar.core.files import atomic_path
    from monoavatar.fit.pose import PoseTrack
    from monoavatar.io.avatar_folder import ShapeFile
    from monoavatar.io.export_mesh import write_obj
    from monoavatar.pipelines.reconstruct import shape_rounds
    from monoavatar.pipelines.stages import StageTimer, pose_stage

    config, inputs, body = _inputs_and_body(args)
    if args.poses is not None:
        track = PoseTrack.load(args.poses)
        if not np.array_equal(track.frame_indices, inputs.observations.frame_indices):
            raise CliError(f"{args.poses} holds poses of other frames than these key-frames "
                           "(run fit-poses with the same input and --frames)")  # fmt: skip
    else:
        track = pose_stage(body, inputs, config.pose, progress=config.progress)
    track, shape = shape_rounds(body, inputs, track, config, StageTimer())
    good = np.flatnonzero(~track.failed)
    ShapeFile(body_model=body.identity, shape=shape.shape.double().numpy(),
              offsets=shape.offsets.double().numpy(), vertices=shape.vertices.double().numpy(),
              faces=shape.faces.numpy(), frames=good[shape.frames],
              frame_shifts=shape.frame_shifts, poses=track.poses,
              translations=track.translations).save(args.output / "shape.npz")  # fmt: skip
    with atomic_path(args.output / "canonical.obj") as tmp:
        write_obj(tmp, shape.vertices.double().numpy(), shape.faces.numpy())
    truth = inputs.ground_truth
    gt = ground_truth_error(body, shape, truth) if truth is not None else None
    print(f"wrote {args.output / 'shape.npz'} and {args.output / 'canonical.obj'}: "
          f"{len(shape.frames)} key-frames, {shape.seconds:.1f} s for the last shape fit"
          + (f"; surface error against the ground truth {gt.surface_error_mm:.2f} mm"
             if gt else ""))  # fmt: skip
    return 0


# -- photo, train -------------------------------------------------------------------------------


def _add_photo(p: argparse.ArgumentParser) -> None:
    from monoavatar.fit.pose import PoseSettings
    from monoavatar.pipelines.photo import PhotoConfig
    from monoavatar.pipelines.stages import InputSettings

    p.description = (
        "Make a rigged, textured avatar from one photograph of a person (dissertation Paper E, "
        "Tex2Shape): the body fitted to mediapipe's mask and keypoints, the photo projected into "
        "the body's UV atlas, a small network turning that partial texture into UV displacement "
        "and normal maps (the unseen back included), the body subdivided and displaced by them. "
        "Writes avatar.glb (skinned, textured), avatar.obj, texture.png, params.npz (usable by "
        "'animate' and 'track --avatar'), maps/normal.png, maps/displacement.npz (metres), "
        "preview/ (input | avatar, partial texture, maps, turntable) and report.json.")
    p.add_argument("input", type=Path, help="a photograph (JPEG, PNG, ...) of one person, "
                   "ideally whole and facing the camera within about 40 degrees")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    _option(p, "--height", PoseSettings, "height", "the person's height in metres, e.g. 1.75 "
            "(without it the avatar is up to scale)", type=float, metavar="M")  # fmt: skip
    _option(p, "--focal", InputSettings, "focal", "focal length in pixels of the original "
            "photo (None: a 68 degree diagonal field of view)", type=float,
            metavar="PX")  # fmt: skip
    _option(p, "--camera", InputSettings, "camera", "a camera.json with the photo's "
            "intrinsics (e.g. a synth folder's)", metavar="JSON")  # fmt: skip
    _option(p, "--weights", PhotoConfig, "weights", "photo-network weights (.safetensors; "
            "None: the shipped ones)", metavar="FILE")  # fmt: skip
    _option(p, "--texture-size", PhotoConfig, "texture_size", "texture pixels", type=int)
    _option(p, "--max-side", PhotoConfig, "max_side", "larger photos are downscaled to this "
            "many pixels on their longer side", type=int)  # fmt: skip
    _option(p, "--device", PhotoConfig, "device", "cpu, or cuda for the network",
            choices=("cpu", "cuda"))  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(run=_run_photo)


def _run_photo(args: argparse.Namespace) -> int:
    from monoavatar.pipelines.photo import PhotoConfig, photo

    config = PhotoConfig()
    config.pose = replace(config.pose, height=args.height)
    config.input = replace(config.input, focal=args.focal,
                           camera=None if args.camera is None else str(args.camera))
    config.weights = None if args.weights is None else str(args.weights)
    config.texture_size = args.texture_size
    config.max_side = args.max_side
    config.device = args.device
    config.progress = not args.quiet
    result = photo(args.input, args.output, config)
    report = result.report
    print(f"avatar written to {result.folder}/")
    print("  avatar.glb  avatar.obj  texture.png  params.npz  maps/  preview/  report.json  "
          "keyframes.jpg")
    fit = report.fit
    print(f"  fit: silhouette IoU {fit.median_silhouette_iou:.2f}, keypoint error "
          f"{fit.keypoint_error_px[0]:.1f} px; height {report.scale.height_m:.2f} m "
          f"({'given' if report.scale.known else 'up to scale'}); "
          f"time {report.seconds:.1f} s")  # fmt: skip
    for warning in report.warnings[:5]:
        print(f"  warning: {warning}")
    _print_view_line(result.folder)
    return 0


def _add_train(p: argparse.ArgumentParser) -> None:
    p.description = ("Train a learned part from data made by our own synth: 'photo' (the "
                     "single-image network of 'monoavatar photo'), 'fast' (the few-frame "
                     "network of 'monoavatar reconstruct --fast'), 'lifter' (the 2D-to-3D "
                     "landmark lifter of 'monoavatar track') or 'face-map' (the face-mesh "
                     "landmarks' places on the body). The networks' training resumes from "
                     "what the output folder already holds.")
    parts = p.add_subparsers(dest="what", required=True, metavar="{photo,fast,lifter,face-map}")
    _add_train_photo(parts.add_parser("photo", help="the photo network (Paper E)"))
    _add_train_fast(parts.add_parser("fast", help="the few-frame network (Paper D)"))
    _add_train_lifter(parts.add_parser("lifter", help="the landmark lifter (Paper A)"))
    _add_train_face_map(parts.add_parser("face-map", help="where the face-mesh landmarks lie "
                                         "on the body's surface (Paper C)"))  # fmt: skip


def _add_train_face_map(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Render the average body with a synth subject's painted face, run mediapipe's face "
        "mesh on it head-on and turned a little either way, back-project its 468 landmarks "
        "onto the body's surface and write OUT/face_map_anny.npz (what monoavatar/body/data/ "
        "ships) and OUT/face_map_preview.png (detections red, the map green). Takes seconds.")
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.set_defaults(run=_run_train_face_map)


def _run_train_face_map(args: argparse.Namespace) -> int:
    import numpy as np

    from monoavatar.body import load_body_model
    from monoavatar.learn.face_map import write_face_map

    built = write_face_map(args.output, load_body_model("anny"))
    spread = np.percentile(built.spread_mm, [50, 90])
    print(f"face map written to {args.output / 'face_map_anny.npz'}; the views agree within "
          f"{spread[0]:.1f} mm (median), {spread[1]:.1f} mm (90th percentile); preview: "
          f"{args.output / 'face_map_preview.png'}")  # fmt: skip
    return 0


def _add_train_lifter(p: argparse.ArgumentParser) -> None:
    from monoavatar.learn.lifter_train import LifterTrainConfig

    p.description = (
        "Make synthetic motion sequences (random bodies in random limb motion, seen by random "
        "cameras), train the landmark lifter to turn a window of noisy 2D landmarks into the "
        "centre frame's 3D landmarks, and write OUT/lifter.safetensors (use it with "
        "'monoavatar track --lifter-weights', or copy it to monoavatar/learn/weights/). Every "
        "step resumes from what OUT already holds.")
    p.add_argument("-o", "--output", required=True, type=Path, help="working folder")
    _option(p, "--sequences", LifterTrainConfig, "sequences", "training sequences", type=int)
    _option(p, "--val", LifterTrainConfig, "val", "validation sequences", type=int)
    _option(p, "--steps", LifterTrainConfig, "steps", "optimiser steps", type=int)
    _option(p, "--batch", LifterTrainConfig, "batch", "windows per step", type=int)
    _option(p, "--seed", LifterTrainConfig, "seed", "training seed", type=int)
    _option(p, "--max-minutes", LifterTrainConfig, "max_minutes", "stop training after this "
            "many minutes (resume by running the command again)", type=float)  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_train_lifter)


def _run_train_lifter(args: argparse.Namespace) -> int:
    from monoavatar.learn.lifter_train import LifterTrainConfig, train_lifter

    config = LifterTrainConfig(sequences=args.sequences, val=args.val, steps=args.steps,
                               batch=args.batch, seed=args.seed, max_minutes=args.max_minutes,
                               progress=not args.quiet)  # fmt: skip
    result = train_lifter(args.output, config)
    return _print_training(result.finished, result.steps_done, result.weights,
                           result.validation, args.output)  # fmt: skip


def _print_training(finished: bool, steps: int, weights: Path, validation: dict[str, float],
                    out: Path) -> int:  # fmt: skip
    state = "finished" if finished else "stopped (run again to resume)"
    print(f"training {state} after {steps} steps" + (f"; weights: {weights}" if finished else ""))
    for key, value in validation.items():
        print(f"  {key}: {value:.2f}")
    print(f"  log: {out / 'train' / 'log.jsonl'}; curve: {out / 'curve.png'}")
    return 0


def _add_train_fast(p: argparse.ArgumentParser) -> None:
    from monoavatar.learn.fast_model import FastNetworkSettings
    from monoavatar.learn.fast_train import FastTrainConfig

    p.description = (
        "Make synthetic turn-around subjects (masks and keypoints as perception gives them, "
        "and their true shape, offsets and poses), train the few-frame network on 1-8 of "
        "their frames at a time, and write OUT/fast.safetensors (use it with 'monoavatar "
        "reconstruct --fast --weights', or copy it to monoavatar/learn/weights/). Every step "
        "resumes from what OUT already holds.")
    p.add_argument("-o", "--output", required=True, type=Path, help="working folder")
    _option(p, "--subjects", FastTrainConfig, "subjects", "training subjects", type=int)
    _option(p, "--val", FastTrainConfig, "val", "validation subjects", type=int)
    _option(p, "--steps", FastTrainConfig, "steps", "optimiser steps", type=int)
    _option(p, "--batch", FastTrainConfig, "batch", "subjects per step", type=int)
    _option(p, "--seed", FastTrainConfig, "seed", "training seed", type=int)
    _option(p, "--device", FastTrainConfig, "device", "where to train", choices=("cpu", "cuda"))
    _option(p, "--workers", FastTrainConfig, "workers", "processes making the data", type=int)
    _option(p, "--max-minutes", FastTrainConfig, "max_minutes", "stop training after this "
            "many minutes (resume by running the command again)", type=float)  # fmt: skip
    _option(p, "--decoder", FastNetworkSettings, "decoder", "the offset decoder: 'linear' "
            "(principal components of the training offsets) or 'uv' (a convolutional map in "
            "the body's UV layout)", choices=("linear", "uv"))  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_train_fast)


def _run_train_fast(args: argparse.Namespace) -> int:
    from monoavatar.learn.fast_model import FastNetworkSettings
    from monoavatar.learn.fast_train import FastTrainConfig, train_fast

    config = FastTrainConfig(subjects=args.subjects, val=args.val, steps=args.steps,
                             batch=args.batch, seed=args.seed, device=args.device,
                             workers=args.workers, max_minutes=args.max_minutes,
                             network=FastNetworkSettings(decoder=args.decoder),
                             progress=not args.quiet)  # fmt: skip
    result = train_fast(args.output, config)
    return _print_training(result.finished, result.steps_done, result.weights,
                           result.validation, args.output)  # fmt: skip


def _add_train_photo(p: argparse.ArgumentParser) -> None:
    from monoavatar.learn.photo_model import PhotoNetworkSettings
    from monoavatar.learn.photo_train import PhotoTrainConfig
    from monoavatar.learn.training import TrainSettings

    p.description = (
        "Measure the "
        "single-image fitter's error on synthetic photos, make training photos with exact UV "
        "maps (the partial texture built from poses perturbed as the fitter errs), train the "
        "photo network (U-Net, MS-DSSIM + L1, a PatchGAN term with --gan-weight) and write "
        "OUT/photo.safetensors (use it with 'monoavatar photo --weights', or copy it to "
        "monoavatar/learn/weights/). Every step resumes from what OUT already holds.")
    p.add_argument("-o", "--output", required=True, type=Path, help="working folder")
    _option(p, "--samples", PhotoTrainConfig, "samples", "training photos", type=int)
    _option(p, "--val", PhotoTrainConfig, "val", "validation photos", type=int)
    _option(p, "--fit-photos", PhotoTrainConfig, "fit_photos", "photos the fitter's error is "
            "measured on (0: train on exact poses)", type=int)  # fmt: skip
    defaults = PhotoTrainConfig().train
    p.add_argument("--steps", type=int, default=defaults.steps,
                   help=f"optimiser steps (default: {defaults.steps})")
    p.add_argument("--batch", type=int, default=defaults.batch,
                   help=f"samples per step (default: {defaults.batch})")
    p.add_argument("--seed", type=int, default=defaults.seed,
                   help=f"training seed (default: {defaults.seed})")
    p.add_argument("--gan-weight", type=float, default=defaults.gan_weight,
                   help=f"weight of the GAN term, 0 disables it (default: {defaults.gan_weight})")
    p.add_argument("--dssim-weight", type=float, default=defaults.dssim_weight,
                   help=f"weight of MS-DSSIM, 0 disables it (default: {defaults.dssim_weight})")
    p.add_argument("--device", choices=("cpu", "cuda"), default=_default(TrainSettings, "device"),
                   help="where to train (default: %(default)s)")
    _option(p, "--tangential-scale", PhotoNetworkSettings, "tangential_scale", "predict the "
            "displacement along the body's normal frame, tangential components times this in "
            "the losses (none: canonical x, y, z)", type=float)  # fmt: skip
    p.add_argument("--classes", action=argparse.BooleanOptionalAction,
                   default=_default(PhotoNetworkSettings, "classes"),
                   help="the network also recognises each texel's garment class and starts "
                        "from that class's mean maps; --no-classes: from the overall mean maps "
                        "(default: %(default)s)")  # fmt: skip
    _option(p, "--workers", PhotoTrainConfig, "workers", "processes making the data", type=int)
    _option(p, "--max-minutes", PhotoTrainConfig, "max_minutes", "stop training after this "
            "many minutes (resume by running the command again)", type=float)  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_train)


def _run_train(args: argparse.Namespace) -> int:
    from monoavatar.learn.photo_train import PhotoTrainConfig, train_photo

    config = PhotoTrainConfig(samples=args.samples, val=args.val, fit_photos=args.fit_photos,
                              workers=args.workers, max_minutes=args.max_minutes,
                              progress=not args.quiet)  # fmt: skip
    config.train = replace(config.train, steps=args.steps, batch=args.batch, seed=args.seed,
                           gan_weight=args.gan_weight, dssim_weight=args.dssim_weight,
                           device=args.device)  # fmt: skip
    config.network = replace(config.network, tangential_scale=args.tangential_scale,
                             classes=args.classes)  # fmt: skip
    result = train_photo(args.output, config)
    state = "finished" if result.train.finished else "stopped (run again to resume)"
    print(f"training {state} after {result.train.steps_done} steps; weights: {result.weights}")
    print(f"  validation curve: {args.output / 'curve.png'}; log: "
          f"{args.output / 'train' / 'log.jsonl'}")  # fmt: skip
    return 0


def _add_transfer(p: argparse.ArgumentParser) -> None:
    from monoavatar.pipelines.transfer import TransferConfig

    p.description = (
        "Garment transfer (dissertation Sec. E.6.5): the person of avatar folder A (face and "
        "body shape) in the clothes of avatar folder B, by exchanging their UV displacement "
        "maps and textures outside the face. A and B are 'photo' or 'reconstruct' folders of "
        "the same body model; the result is an avatar folder like 'photo' writes.")
    p.add_argument("a", type=Path, help="the avatar folder whose person is kept")
    p.add_argument("b", type=Path, help="the avatar folder whose clothes are taken")
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    _option(p, "--border", TransferConfig, "border", "blend width between A's face and B's "
            "clothes, texels of the 256² maps", type=int)  # fmt: skip
    p.set_defaults(run=_run_transfer)


def _run_transfer(args: argparse.Namespace) -> int:
    from monoavatar.pipelines.transfer import TransferConfig, transfer

    result = transfer(args.a, args.b, args.output, TransferConfig(border=args.border))
    print(f"avatar written to {result.folder}/ (turntable: "
          f"{result.folder / 'preview' / 'turntable.png'})")  # fmt: skip
    return 0


def _add_measure(p: argparse.ArgumentParser) -> None:
    from monoavatar.pipelines.measure import UNDER, MeasureConfig

    p.description = ("Tailor's measurements of an avatar folder (reconstruct, photo): height; "
                     "chest, waist, hip, neck, upper-arm, thigh and calf girths; shoulder "
                     "width, arm length, inseam; each on the body under the clothes and on the "
                     "clothed surface. Writes FOLDER/measurements.json (metres, or fractions of "
                     "the height for an avatar made without --height) and "
                     "FOLDER/preview/measurements.png.")  # fmt: skip
    p.add_argument("avatar", type=Path, help="an avatar folder")
    p.add_argument("--json", type=Path, default=None, metavar="FILE",
                   help="write the JSON here instead (default: FOLDER/measurements.json)")
    _option(p, "--under", MeasureConfig, "under", choices=UNDER,
            help="the body under the clothes: 'fit' re-fits the body model's shape to lie "
            "inside the clothed surface, 'clamp' keeps the avatar's shape with its inward "
            "offsets")  # fmt: skip
    p.add_argument("--no-picture", action="store_true", help="skip preview/measurements.png")
    p.set_defaults(run=_run_measure)


def _run_measure(args: argparse.Namespace) -> int:
    from monoavatar.pipelines.measure import MeasureConfig, measure_folder

    result = measure_folder(args.avatar, args.json,
                            MeasureConfig(under=args.under, picture=not args.no_picture))
    metric = result.scale_known
    unit = "cm" if metric else "% of height"
    print(f"{'measurement':<16}{'body':>9}{'clothed':>9}  ({unit})")
    for name, vals in result.values.items():
        cells = "".join(f"{'-' if v is None else f'{100 * v:.1f}':>9}"
                        for v in (vals["body"], vals["clothed"]))  # fmt: skip
        print(f"{name:<16}{cells}")
    if not metric:
        print("the avatar's scale is unknown (made without --height): values are fractions of "
              "the body's height")
    print("wrote " + " and ".join(str(p) for p in result.files.values()))
    return 0


# -- animate, demo, bench ---------------------------------------------------------------------


def _add_animate(p: argparse.ArgumentParser) -> None:
    p.description = ("Write the avatar of a 'monoavatar reconstruct' folder as an animated glTF "
                     "2.0 binary: a built-in motion (walk, wave) or the poses of another "
                     "params.npz.")  # fmt: skip
    p.add_argument("avatar", type=Path, help="a folder written by 'monoavatar reconstruct'")
    p.add_argument("-o", "--output", required=True, type=Path, help="the .glb to write")
    p.add_argument("--motion", default="walk",
                   help="walk (default), wave, or a path to a params.npz / poses.npz")  # fmt: skip
    p.add_argument("--frames", type=int, default=None, help="frames of a built-in motion")
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.set_defaults(run=_run_animate)


def _run_animate(args: argparse.Namespace) -> int:
    from monoavatar.pipelines.animate import animate_folder

    path = animate_folder(args.avatar, args.motion, args.output, frames=args.frames,
                          fps=args.fps, overwrite=args.force)  # fmt: skip
    print(f"wrote {path}")
    return 0


def _add_view(p: argparse.ArgumentParser) -> None:
    p.description = ("Look at an avatar in a browser: the textured avatar under orbit controls "
                     "beside the input frames with the fitted avatar over them, its motions, "
                     "and for a synthetic input the error heat map. Serves a local page "
                     "(nothing is fetched from the network), or writes it as one "
                     "self-contained HTML file with --html.")  # fmt: skip
    p.add_argument("avatar", type=Path,
                   help="a folder written by reconstruct, photo or track, or a .glb written by "
                        "animate")  # fmt: skip
    p.add_argument("--port", type=int, default=8000, help="port on 127.0.0.1 (default 8000)")
    p.add_argument("--html", type=Path, default=None,
                   help="write the page to this .html file instead of serving it")
    p.add_argument("--no-motions", action="store_true",
                   help="leave out the built-in motions (no body model is loaded)")
    p.set_defaults(run=_run_view)


def _run_view(args: argparse.Namespace) -> int:
    from monoavatar.core.errors import InputError
    from monoavatar.io.viewer_page import page_html, serve_page, write_page
    from monoavatar.pipelines.view import ViewConfig, viewer_page

    if args.html is not None and args.html.suffix.lower() not in (".html", ".htm"):
        raise InputError(args.html, "the page is written as HTML: give a .html path")
    if not 0 <= args.port <= 65535:
        raise MonoavatarError(f"--port must lie in [0, 65535], got {args.port}")
    page = viewer_page(args.avatar, ViewConfig(motions=() if args.no_motions else
                                               ViewConfig().motions))  # fmt: skip
    if args.html is not None:
        path = write_page(args.html, page)
        print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB; open it in any browser)")
        return 0
    server = serve_page(page_html(page), args.port)
    port = server.server_address[1]
    print(f"monoavatar view: http://127.0.0.1:{port}/ (Ctrl-C to stop)", flush=True)
    try:
        server.serve_forever()
    finally:
        server.server_close()
    return 0


def _add_demo(p: argparse.ArgumentParser) -> None:
    p.description = ("The embedded default: render a synthetic person turning around "
                     "(monoavatar synth turnaround), reconstruct an avatar from the rendered "
                     "video with mediapipe perception, and print its surface error against "
                     "the ground truth.")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--frames", type=int, default=40, help="frames of the video (default 40)")
    p.add_argument("--seed", type=int, default=3, help="subject and scene seed (default 3)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    from monoavatar.pipelines.reconstruct import ReconstructConfig, reconstruct
    from monoavatar.pipelines.stages import InputSettings
    from monoavatar.synth.scene import SynthConfig, generate

    scene = args.output / "input"
    if not (scene / "scene.json").is_file():
        generate(scene, SynthConfig(kind="turnaround", frames=args.frames, seed=args.seed),
                 progress=not args.quiet)  # fmt: skip
    config = ReconstructConfig(input=InputSettings(frames=args.frames, perception="mediapipe"),
                               progress=not args.quiet)  # fmt: skip
    result = reconstruct(scene, args.output / "avatar", config)
    _with_ground_truth(result, result.body)
    print(f"input video: {scene / 'video.mp4'} (ground truth in {scene / 'gt'})")
    _print_summary(result.report, result.out_dir)
    return 0


def _add_bench(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Generate the fixed, versioned suite of synthetic turn-around subjects (minimal "
        "clothing and clothed, from fixed seeds; cached in OUT/scenes), reconstruct each with "
        "mediapipe perception and fitted poses, and with ground-truth poses, and write "
        "results.json, results.md (a table beside Table B.1 of the dissertation) and "
        "per-vertex error heat maps. The texture PSNR poses each finished avatar in frames it "
        "was not built from with our tracker (the key-frames' poses interpolated, then flow "
        "rounds on those frames). Suite v1 takes about 40 minutes on 2 CPU cores, suite v2's "
        "dev split about 20 and its test split about 40.")
    p.add_argument("-o", "--output", type=Path, default=Path("out/bench"),
                   help="output folder (default: %(default)s)")  # fmt: skip
    p.add_argument("--quick", action="store_true",
                   help="one small subject with few frames: a smoke test of a few minutes")
    p.add_argument("--subjects", nargs="+", default=None, metavar="NAME",
                   help="run only these suite subjects")  # fmt: skip
    p.add_argument("--suite", choices=("v1", "v2"), default="v1",
                   help="v1: the suite of studio takes (Table B.1's setting); v2: the harder "
                   "suite, phone takes of wide subjects reconstructed from their video with "
                   "the focal length and height given, in a dev and a sealed test split "
                   "(--split) (default: %(default)s)")  # fmt: skip
    p.add_argument("--no-gt-poses", action="store_true",
                   help="skip the runs with ground-truth poses")  # fmt: skip
    p.add_argument("--measure-only", action="store_true",
                   help="reconstruct nothing: measure the runs an earlier benchmark left in "
                   "OUT/runs again (after the metrics changed); times are those the runs "
                   "reported")  # fmt: skip
    p.add_argument("--track-rounds", type=int, default=3, metavar="N",
                   help="flow rounds of the tracker that poses the avatar in the held-out "
                   "frames for the texture PSNR (0: the key-frames' poses interpolated; "
                   "default: %(default)s)")  # fmt: skip
    p.add_argument("--workers", type=int, default=2, metavar="N",
                   help="threads of the flow and texture stages and of the tracker "
                   "(default: %(default)s)")  # fmt: skip
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="run the scenes and runs as Ray tasks (pip install "
                   "'monoavatar[ray]'): 'local' starts a cluster on this machine's cores, "
                   "'auto', HOST:6379 or ray://HOST:10001 joins a running one (started with "
                   "'ray start'; OUT must then be a folder every node sees); each run reserves "
                   "--workers cores")  # fmt: skip
    p.add_argument("--tracking", action="store_true",
                   help="instead, the tracking table (Paper A, Table A.1): 'monoavatar track' "
                   "on the suite's walk and jog sequences (about 7 minutes; with --quick one "
                   "short walk) into OUT/tracking.md and OUT/tracking.json")  # fmt: skip
    p.add_argument("--photo", action="store_true",
                   help="instead, the photo table (Paper E, Table E.1): 'monoavatar photo' on "
                   "12 sealed synthetic test photos (about 3 minutes; with --quick two) into "
                   "OUT/photo.md, OUT/photo.json and the plots OUT/photo_yaw.png, "
                   "OUT/photo_fill.png")  # fmt: skip
    p.add_argument("--fast", action="store_true",
                   help="instead, the few-frame table (Paper D, Table D.1): 'reconstruct "
                   "--fast' on the suite's subjects from 1, 2, 4 and 8 frames, before and after "
                   "refinement, beside the full pipeline on the same 8 frames (about an hour "
                   "on 2 cores; with --quick one small subject, about 4 minutes) into "
                   "OUT/fast.md, OUT/fast.json and the refinement curve OUT/fast_refine.png "
                   "(Fig. D.7)")  # fmt: skip
    p.add_argument("--weights", type=Path, default=None, metavar="FILE",
                   help="with --photo or --fast: the network's weights (default: the shipped "
                   "ones)")  # fmt: skip
    p.add_argument("--split", choices=("dev", "test"), default="test",
                   help="with --photo or --suite v2: 'dev' runs the validation photos or "
                   "subjects (choose settings there), 'test' the sealed test ones, only to "
                   "report a finished change (default: %(default)s)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_bench)


def _run_bench(args: argparse.Namespace) -> int:
    from monoavatar.bench.runner import run_bench

    if args.track_rounds < 0:
        raise CliError(f"--track-rounds must be >= 0, got {args.track_rounds}")
    if args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    if args.split != "test" and not (args.photo or args.suite == "v2"):
        raise CliError("--split dev goes with --photo or --suite v2 (the other tables have "
                       "their own fixed scenes)")  # fmt: skip
    if args.suite == "v2" and (args.quick or args.tracking or args.fast or args.photo):
        raise CliError("--suite v2 is the reconstruction suite; it does not go with --quick, "
                       "--tracking, --fast or --photo")  # fmt: skip
    if args.address is not None and (args.tracking or args.fast or args.photo):
        raise CliError("--address runs the reconstruction suite; it does not go with "
                       "--tracking, --fast or --photo")  # fmt: skip
    if args.tracking:
        from monoavatar.bench.tracking import render_tracking_markdown, run_tracking_bench

        results = run_tracking_bench(args.output, quick=args.quick, progress=not args.quiet)
        print(render_tracking_markdown(results["sequences"]))
        print(f"results: {args.output / 'tracking.md'} and {args.output / 'tracking.json'}")
        return 0
    if args.fast:
        from monoavatar.bench.fast import render_fast_markdown, run_fast_bench

        results = run_fast_bench(args.output, quick=args.quick, subjects=args.subjects,
                                 progress=not args.quiet,
                                 weights=None if args.weights is None else str(args.weights))
        print(render_fast_markdown(results["runs"]))
        print(f"results: {args.output / 'fast.md'} and {args.output / 'fast.json'}")
        return 0
    if args.photo:
        from monoavatar.bench.photo import render_photo_markdown, run_photo_bench

        results = run_photo_bench(args.output, quick=args.quick, progress=not args.quiet,
                                  weights=None if args.weights is None else str(args.weights),
                                  split=args.split)  # fmt: skip
        print(render_photo_markdown(results["photos"]))
        print(f"results: {args.output / 'photo.md'} and {args.output / 'photo.json'}")
        return 0
    run_bench(args.output, quick=args.quick, subjects=args.subjects,
              gt_poses=not args.no_gt_poses, suite_name=args.suite, split=args.split,
              progress=not args.quiet,
              measure_only=args.measure_only, track_rounds=args.track_rounds,
              workers=args.workers, address=args.address)  # fmt: skip
    print(f"results: {args.output / 'results.md'} and {args.output / 'results.json'}")
    return 0


# -- batch ------------------------------------------------------------------------------------


def _add_batch(p: argparse.ArgumentParser) -> None:
    from monoavatar.batch import COMMANDS, BatchSettings

    p.description = (
        "Run reconstruct, photo or track on many inputs, each into OUT/<name>/ exactly as the "
        "single command writes it, with its output in OUT/<name>/log.txt and a summary in "
        "OUT/batch.json. With Ray installed (pip install 'monoavatar[ray]') every input is a "
        "task of a local Ray cluster, or of an existing one with --address (OUT must then be "
        "a folder every node sees); without Ray the inputs run one after another. A failed "
        "input does not stop the others; a second run skips the complete folders and retries "
        "the rest; Ctrl-C interrupts the running commands, which leave nothing half-written.")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="videos, image folders, People-Snapshot or synth folders, photos (for "
                   "--command photo), or .txt files listing them one a line")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    _option(p, "--command", BatchSettings, "command", "what to run on each input",
            choices=tuple(COMMANDS))  # fmt: skip
    p.add_argument("--options", default="", metavar="'OPTIONS'",
                   help="the command's own options, quoted as one argument, e.g. "
                   "--options '--fast --height 1.75' (default: none)")  # fmt: skip
    _option(p, "--address", BatchSettings, "address", "an existing Ray cluster's address "
            "(e.g. ray://head:10001; start one with Ray's own 'ray start --head'); without it "
            "a local cluster on this machine's cores", metavar="ADDR")  # fmt: skip
    _option(p, "--cpus-per-task", BatchSettings, "cpus_per_task", "cores reserved for "
            "each input (its numerical libraries use as many threads)", type=int,
            metavar="N")  # fmt: skip
    p.add_argument("--no-ray", action="store_true",
                   help="run the inputs one after another even with Ray installed")
    p.add_argument("--quiet", action="store_true", help="no status table")
    p.set_defaults(run=_run_batch)


def _run_batch(args: argparse.Namespace) -> int:
    import shlex

    from monoavatar.batch import BatchSettings, run_batch

    try:
        options = tuple(shlex.split(args.options))
    except ValueError as exc:
        raise CliError(f"--options: {exc}") from exc
    _check_command_options(args.command, options)
    settings = BatchSettings(command=args.command, options=options, address=args.address,
                             cpus_per_task=args.cpus_per_task, use_ray=not args.no_ray,
                             progress=not args.quiet)  # fmt: skip
    result = run_batch(args.inputs, args.output, settings)
    counts = {s: sum(i.status == s for i in result.items)
              for s in ("done", "skipped", "failed", "interrupted")}  # fmt: skip
    print(f"{counts['done']} done, {counts['skipped']} complete already, {counts['failed']} "
          f"failed in {result.seconds:.0f} s; summary: {result.summary}")  # fmt: skip
    for item in result.failed:
        print(f"  {item.name}: {item.error} (log: {Path(item.output) / 'log.txt'})")
    return 1 if result.failed else 0


def _check_command_options(command: str, options: tuple[str, ...]) -> None:
    """Refuse options the command does not have before any input runs."""
    import contextlib
    import io

    parser = build_parser(only=command)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            parser.parse_args([command, "INPUT", "-o", "OUT", *options])
    except SystemExit as exc:
        message = err.getvalue().strip().splitlines()[-1:] or ["invalid options"]
        raise CliError(f"--options for {command}: {message[0].split('error: ')[-1]}") from exc


# -- the parser -------------------------------------------------------------------------------

VERBS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None]]] = {
    "demo": ("synthesise a short turn-around video and reconstruct an avatar from it",
             _add_demo),
    "reconstruct": ("video of a person turning around -> textured, rigged avatar (glb, obj)",
                    _add_reconstruct),
    "fit-poses": ("fit a body shape and per-frame 3D poses to a video (Sec. B.3.2)",
                  _add_fit_poses),
    "fit-shape": ("consensus shape (body shape + per-vertex offsets) of a turning person "
                  "(Sec. B.3.3)", _add_fit_shape),
    "track": ("3D motion of a person through a video by optical flow (npz, bvh, glb)",
              _add_track),
    "photo": ("one photograph of a person → a rigged, textured avatar (Paper E)", _add_photo),
    "train": ("train a learned part (photo, fast) on data made by synth", _add_train),
    "transfer": ("dress the person of one avatar folder in another's clothes (Sec. E.6.5)",
                 _add_transfer),
    "measure": ("body measurements of an avatar (girths, lengths), under and over the clothes",
                _add_measure),
    "animate": ("re-pose an avatar with a built-in motion or another video's poses "
                "(animated glb)", _add_animate),
    "view": ("look at an avatar, its fit and its motion in a browser (or one HTML file)",
             _add_view),
    "batch": ("run reconstruct, photo or track on many inputs (Ray tasks when Ray is installed)",
              _add_batch),
    "bench": ("measure accuracy and speed on a fixed synthetic suite, beside the dissertation",
              _add_bench),
    "synth": ("render a synthetic ground-truth scene (frames, masks, keypoints, meshes)",
              _add_synth),
    "body": ("write a posed body model as OBJ with a preview image (a quick check of set-up)",
             _add_body),
}  # fmt: skip
"""Verb → (one-line help, the function that adds its options and ``run``)."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser; with ``only``, just that verb's options are built (the others' names and
    help lines only, so that ``monoavatar --help`` stays fast)."""
    parser = argparse.ArgumentParser(
        prog="monoavatar",
        description="Animatable, textured 3D avatars and 3D motion from monocular video.",
    )
    parser.add_argument("--version", action="version", version=f"monoavatar {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (summary, add) in VERBS.items():
        p = sub.add_parser(name, help=summary, description=summary)
        if only is None or only == name:
            add(p)
    return parser


def _show_warning(verb: str, message: Warning | str, category: type[Warning], filename: str,
                  lineno: int, file: Any = None, line: str | None = None) -> None:  # fmt: skip
    """``warnings.showwarning`` for the CLI: ``monoavatar VERB: warning: MESSAGE`` for ours,
    the category named for other libraries' (no source line either way)."""
    ours = "monoavatar" in filename or issubclass(category, InputWarning)
    label = "warning" if ours else f"warning from {Path(filename).name} ({category.__name__})"
    print(f"monoavatar {verb}: {label}: {message}", file=file or sys.stderr)


def _raise_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


@contextmanager
def _interruptible() -> Iterator[None]:
    """SIGINT (Ctrl-C) and SIGTERM (``kill``) stop the command as Ctrl-C on a terminal does:
    staged files removed, a batch's running commands stopped. Also where the process started
    with SIGINT ignored (a script's background job), where Python raises no KeyboardInterrupt;
    the commands a batch starts then inherit the default disposition, not the ignored one.
    The previous handlers come back afterwards (``main`` called in-process)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set in the main thread
        return
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


@contextmanager
def _drop_if_empty(folder: Path | None) -> Iterator[None]:
    """Remove ``folder`` (one this run created) if the run fails and leaves it empty."""
    try:
        yield
    except BaseException:
        if folder is not None and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
        raise


def _os_hint(exc: OSError) -> str:
    """What to do about the operating system errors a user can fix."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return " (the disk is full: free some space or write the output elsewhere with -o)"
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return " (permission denied: check the path, or write the output elsewhere with -o)"
    return ""


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    verb = next((a for a in argv if not a.startswith("-")), "")
    parser = build_parser(only=verb)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    output = getattr(args, "output", None)
    created = isinstance(output, Path) and not output.exists()
    try:
        with (warnings.catch_warnings(), _interruptible(),
              _drop_if_empty(output if created else None)):  # fmt: skip
            warnings.showwarning = partial(_show_warning, args.command)
            return int(args.run(args))
    except MonoavatarError as exc:
        print(f"monoavatar {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the output piped into a program that stopped reading (head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a file that cannot be read or written
        print(f"monoavatar {args.command}: error: {exc}{_os_hint(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
