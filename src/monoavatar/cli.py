"""The ``monoavatar`` command line: one sub-command per capability."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monoavatar import __version__

if TYPE_CHECKING:  # the CLI imports the pipeline lazily, so that --help stays fast
    from monoavatar.perception import PerceptionSettings
    from monoavatar.reconstruct import ReconstructConfig


class CliError(Exception):
    """A user-facing error: printed without a traceback, exit code 2."""


def _add_synth(sub: argparse._SubParsersAction) -> None:
    from monoavatar.synth.options import BACKGROUNDS, CLOTHING, KINDS, NOISE_LEVELS

    p = sub.add_parser(
        "synth",
        help="render a synthetic ground-truth scene (frames, masks, keypoints, meshes)",
        description="Render a person with known 3D shape, clothing, texture and motion through "
        "a fixed camera, and write frames, a video, exact masks, 2D keypoints, the camera, "
        "ground-truth meshes and parameters, and a contact sheet. The same seed gives the "
        "same scene.",
    )
    p.add_argument(
        "kind",
        choices=KINDS,
        help="turnaround: one turn in an A-pose; motion: "
        "walking, waving, jogging in place; photo: single images, one person each",
    )
    p.add_argument("-o", "--output", required=True, type=Path, help="new or empty folder")
    p.add_argument("--frames", type=int, default=120, help="number of frames (default 120)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--size",
        type=int,
        nargs=2,
        default=(540, 540),
        metavar=("W", "H"),
        help="image size in pixels, even (default 540 540)",
    )
    p.add_argument(
        "--clothing",
        choices=CLOTHING,
        default=None,
        help="garment set (default: drawn from the seed)",
    )
    p.add_argument(
        "--noise",
        choices=list(NOISE_LEVELS),
        default="low",
        help="image noise, blur, JPEG and keypoint jitter (default low)",
    )
    p.add_argument(
        "--background",
        choices=BACKGROUNDS,
        default=None,
        help="background (default: drawn from the seed)",
    )
    p.add_argument("--texture-size", type=int, default=1024, help="texture pixels (default 1024)")
    p.add_argument(
        "--posed-every",
        type=int,
        default=10,
        help="write the posed ground-truth mesh every N frames (default 10)",
    )
    p.set_defaults(run=_run_synth)


def _run_synth(args: argparse.Namespace) -> int:
    from monoavatar.synth.scene import SynthConfig, SynthError, generate

    config = SynthConfig(
        kind=args.kind,
        frames=args.frames,
        seed=args.seed,
        width=args.size[0],
        height=args.size[1],
        clothing=args.clothing,
        noise=args.noise,
        background=args.background,
        texture_size=args.texture_size,
        posed_every=args.posed_every,
    )
    try:
        summary = generate(args.output, config)
    except SynthError as exc:
        raise CliError(str(exc)) from exc
    print(
        f"wrote {summary.frames} frames of {summary.subjects} subject(s) to {summary.folder} "
        f"in {summary.seconds:.1f} s\n"
        f"  preview: {summary.folder / 'preview' / 'contact_sheet.png'}\n"
        f"  description: {summary.folder / 'scene.json'}"
    )
    return 0


def _add_body(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "body",
        help="write a posed body model as OBJ with a preview image (a quick check of set-up)",
        description="Pose the body model (Anny by default, or your SMPL file) and write it as "
        "an OBJ with UVs and a preview PNG.",
    )
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument(
        "--model",
        default="anny",
        help="'anny' (default), 'anny-local', or a path to an SMPL .npz/.pkl",
    )
    p.add_argument("--pose", choices=("rest", "wave", "walk"), default="wave")
    p.set_defaults(run=_run_body)


def _run_body(args: argparse.Namespace) -> int:
    import numpy as np
    import torch
    from PIL import Image

    from monoavatar.body import BodyModelError, load_body_model
    from monoavatar.camera import PinholeCamera
    from monoavatar.io.export_mesh import write_obj
    from monoavatar.render import rasterize, render_normals

    try:
        body = load_body_model(args.model)
    except BodyModelError as exc:
        raise CliError(str(exc)) from exc
    pose = body.zero_pose()
    names = body.joint_names
    if args.pose == "wave" and "shoulder_r" in names:
        pose[0, names.index("shoulder_r"), 2] = -1.5
        pose[0, names.index("elbow_r"), 2] = -1.0
    elif args.pose == "walk" and "hip_l" in names:
        pose[0, names.index("hip_l"), 0] = -0.4
        pose[0, names.index("knee_r"), 0] = 0.6
        pose[0, names.index("shoulder_l"), 0] = 0.4
    try:
        args.output.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"cannot create {args.output}: {exc}") from exc
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


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions whose message is meant for the user (no traceback)."""
    from monoavatar.body import BodyModelError
    from monoavatar.camera import CameraError
    from monoavatar.fit.pose import PoseFitError
    from monoavatar.fit.shape import ShapeFitError
    from monoavatar.io.errors import InputError
    from monoavatar.perception.errors import PerceptionError
    from monoavatar.reconstruct import ReconstructError
    from monoavatar.texture.atlas import TextureError

    return (BodyModelError, CameraError, PoseFitError, ShapeFitError, InputError,
            PerceptionError, ReconstructError, TextureError)  # fmt: skip


def _add_input_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path,
                   help="a video file (mp4, mov, avi, webm), a folder of images, a "
                   "People-Snapshot folder, or a folder written by 'monoavatar synth'")  # fmt: skip
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output folder (created; existing result files are replaced)")  # fmt: skip
    p.add_argument("--frames", type=int, default=120,
                   help="key-frames to use, spread evenly over the input (default 120)")
    p.add_argument("--height", type=float, default=None, metavar="M",
                   help="the person's height in metres, e.g. 1.75; without it the result is "
                   "up to scale (an average height is assumed)")  # fmt: skip
    p.add_argument("--focal", type=float, default=None, metavar="PX",
                   help="focal length in pixels (default: a 68 degree diagonal field of view, "
                   "typical of phone cameras; a synth or People-Snapshot folder brings its own)")
    p.add_argument("--camera", type=str, default=None, metavar="JSON",
                   help="a camera.json with the intrinsics instead of --focal")  # fmt: skip
    p.add_argument("--perception", choices=("auto", "mediapipe", "ground-truth"),
                   default="auto",
                   help="masks and keypoints: auto (a synth or People-Snapshot folder's own, "
                   "else mediapipe; default), mediapipe, or ground-truth")  # fmt: skip
    p.add_argument("--no-grabcut", action="store_true",
                   help="keep mediapipe's person masks as they are, without the GrabCut "
                   "refinement of their boundary (on by default; about 0.06 s per frame)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _perception_settings(args: argparse.Namespace) -> PerceptionSettings:
    """The perception options of :func:`_add_input_options`."""
    from monoavatar.perception import PerceptionSettings

    return PerceptionSettings(grabcut=not args.no_grabcut)


def _input_config(args: argparse.Namespace, **options: Any) -> ReconstructConfig:
    """The configuration from the input options of :func:`_add_input_options`, plus
    ``options``."""
    from monoavatar.reconstruct import ReconstructConfig

    return ReconstructConfig(frames=args.frames, height=args.height, focal=args.focal,
                             camera=args.camera, perception=args.perception,
                             perception_settings=_perception_settings(args),
                             progress=not args.quiet, **options)  # fmt: skip


def _add_reconstruct(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reconstruct",
        help="video of a person turning around -> textured, rigged avatar (glb, obj)",
        description="Reconstruct a textured, rigged avatar from a video of a person turning "
        "around in front of a static camera (dissertation Paper B): perception, pose fitting, "
        "consensus shape with per-vertex offsets, texture, and export to avatar.glb (skinned, "
        "textured glTF 2.0), avatar.obj/.mtl + texture.png, params.npz, report.json and "
        "preview images. Stages that ran before on the same input and settings are reused "
        "from the cache ($MONOAVATAR_CACHE, default ~/.cache/monoavatar).",
    )
    _add_input_options(p)
    p.add_argument("--texture-size", type=int, default=1024, metavar="S",
                   help="texture side in texels (default 1024)")  # fmt: skip
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="where to compute (default cpu; every stage runs on the CPU)")  # fmt: skip
    p.add_argument("--poses", choices=("fit", "ground-truth"), default="fit",
                   help="fit the poses (default), or take a synth folder's true poses "
                   "(benchmarks of the shape stage)")  # fmt: skip
    p.add_argument("--no-offsets", action="store_true",
                   help="fit the body model's shape only, without per-vertex offsets "
                   "(the baseline of the benchmark)")  # fmt: skip
    p.add_argument("--refine-rounds", type=int, default=0, metavar="R",
                   help="rounds of pose re-fitting with the consensus shape by keypoints and "
                   "silhouette, each followed by the shape again, before the texture (default "
                   "0: the flow rounds re-fit the poses with the shape)")
    p.add_argument("--flow-rounds", type=int, default=3, metavar="R",
                   help="rounds of key-frame pose refinement by optical flow from the textured "
                   "avatar to each frame and by the outline, each followed by the shape and "
                   "the texture again (default 3; about 0.15 s per key-frame and round for the "
                   "flow on 2 cores, plus a shape and a texture; 0 turns it off)")
    p.add_argument("--workers", type=int, default=2, metavar="N",
                   help="threads that fit and texture key-frames side by side in the flow "
                   "and texture stages (default 2; 1 makes runs bit-reproducible, 2 lets the "
                   "result vary between runs by float rounding: about 0.03 mm of surface error)")
    p.add_argument("--model", default="anny",
                   help="body model: anny (default) or a path to your SMPL .npz/.pkl")  # fmt: skip
    p.set_defaults(run=_run_reconstruct)


def _run_reconstruct(args: argparse.Namespace) -> int:
    from monoavatar.reconstruct import ReconstructConfig, reconstruct

    config = ReconstructConfig(
        frames=args.frames, height=args.height, focal=args.focal, camera=args.camera,
        texture_size=args.texture_size, device=args.device, perception=args.perception,
        poses=args.poses, body_model=args.model, offsets=not args.no_offsets,
        refine_rounds=args.refine_rounds, flow_rounds=args.flow_rounds, workers=args.workers,
        perception_settings=_perception_settings(args), progress=not args.quiet,
    )  # fmt: skip
    try:
        result = reconstruct(args.input, args.output, config)
    except _user_errors() as exc:
        raise CliError(str(exc)) from exc
    _print_summary(result.report, result.out_dir)
    return 0


def _print_summary(report: dict, out: Path) -> None:
    t = report["timings"]
    fit = report["fit"]
    failed = int(sum(fit["failed"]))
    print(f"avatar written to {out}/")
    print("  avatar.glb  avatar.obj  texture.png  params.npz  report.json  preview/")
    print(f"  key-frames: {report['input']['frames']}  failed: {failed}  "
          f"median silhouette IoU: {fit['median_silhouette_iou']:.3f}")  # fmt: skip
    print(f"  height: {report['scale']['height_m']:.3f} m ({report['scale']['note']})")
    print("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items())
          + f"; total {report['seconds']:.1f} s")  # fmt: skip
    if "ground_truth" in report:
        gt = report["ground_truth"]
        print(f"  surface error against the ground truth: {gt['surface_error_mm']:.2f} mm "
              f"after pose and scale alignment ({gt['surface_error_rigid_mm']:.2f} mm "
              "after a similarity transform alone)")  # fmt: skip
    for warning in report.get("warnings", [])[:5]:
        print(f"  warning: {warning}")


def _add_fit_poses(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit-poses",
        help="fit a body shape and per-frame 3D poses to a video (Sec. B.3.2)",
        description="Fit one body shape and a 3D pose per key-frame to the person masks and "
        "2D keypoints of a video. Writes OUT/poses.npz (shape, poses (axis-angle radians), "
        "translations (metres), camera, per-frame keypoint error, silhouette IoU and failure "
        "flags).",
    )
    _add_input_options(p)
    p.set_defaults(run=_run_fit_poses)


def _run_fit_poses(args: argparse.Namespace) -> int:
    import numpy as np

    from monoavatar.body import load_body_model
    from monoavatar.reconstruct import load_inputs, run_poses

    config = _input_config(args)
    try:
        config.validate()
        args.output.mkdir(parents=True, exist_ok=True)
        inputs = load_inputs(args.input, config)
        body = load_body_model("anny")
        track = run_poses(body, inputs, config)
    except OSError as exc:
        raise CliError(f"cannot write to {args.output}: {exc}") from exc
    except _user_errors() as exc:
        raise CliError(str(exc)) from exc
    track.save(args.output / "poses.npz")
    good = ~track.failed
    print(f"wrote {args.output / 'poses.npz'}: {len(track.poses)} frames, "
          f"{int((~good).sum())} failed, median keypoint error "
          f"{np.nanmedian(track.keypoint_error):.1f} px, median silhouette IoU "
          f"{np.median(track.silhouette_iou):.3f}, {track.seconds:.1f} s; height "
          f"{track.height:.2f} m ({'given' if track.scale_known else 'up to scale'})")  # fmt: skip
    return 0


def _add_fit_shape(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit-shape",
        help="consensus shape (body shape + per-vertex offsets) of a turning person "
        "(Sec. B.3.3)",
        description="Fit the consensus shape of the person in a video: silhouette rays of "
        "every key-frame unposed into the canonical pose, the body model's shape and per-vertex "
        "offsets fitted to them, alternating with re-fits of the poses. Poses come from "
        "'monoavatar fit-poses' (--poses) or are fitted (and cached) first. Writes "
        "OUT/shape.npz (shape, offsets (metres), canonical vertices and faces, the frames used, "
        "their translation corrections, poses and translations) and OUT/canonical.obj; on a "
        "synth folder prints the surface error against the ground truth.",
    )
    _add_input_options(p)
    p.add_argument("--poses", type=Path, default=None, metavar="NPZ",
                   help="a poses.npz from 'monoavatar fit-poses' on the same input and "
                   "--frames (default: fit the poses here)")  # fmt: skip
    p.add_argument("--no-offsets", action="store_true",
                   help="the body model's shape only (the shape-only baseline)")
    p.add_argument("--refine-rounds", type=int, default=1, metavar="R",
                   help="rounds of pose re-fitting with the consensus shape (default 1)")
    p.set_defaults(run=_run_fit_shape)


def _run_fit_shape(args: argparse.Namespace) -> int:
    import numpy as np

    from monoavatar.body import load_body_model
    from monoavatar.fit.pose import PoseTrack
    from monoavatar.io.export_mesh import atomic_path, write_obj
    from monoavatar.reconstruct import (
        ReconstructError,
        ground_truth_error,
        load_inputs,
        run_poses,
        run_shape_rounds,
    )

    config = _input_config(args, offsets=not args.no_offsets, refine_rounds=args.refine_rounds)
    try:
        config.validate()
        args.output.mkdir(parents=True, exist_ok=True)
        inputs = load_inputs(args.input, config)
        body = load_body_model("anny")
        if args.poses is not None:
            track = PoseTrack.load(args.poses)
            if not np.array_equal(track.frame_indices, inputs.observations.frame_indices):
                raise ReconstructError(
                    f"{args.poses} holds poses of other frames than these key-frames (run "
                    "fit-poses with the same input and --frames)"
                )
        else:
            track = run_poses(body, inputs, config)
        track, shape = run_shape_rounds(body, inputs, track, config)
        good = np.flatnonzero(~track.failed)
        with atomic_path(args.output / "shape.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, shape=shape.shape.double().numpy(),
                         offsets=shape.offsets.double().numpy(),
                         vertices=shape.vertices.double().numpy(), faces=shape.faces.numpy(),
                         frames=good[shape.frames], frame_shifts=shape.frame_shifts,
                         poses=track.poses, translations=track.translations,
                         body_model=body.identity)  # fmt: skip
        with atomic_path(args.output / "canonical.obj") as tmp:
            write_obj(tmp, shape.vertices.double().numpy(), shape.faces.numpy())
    except OSError as exc:
        raise CliError(f"cannot read or write: {exc}") from exc
    except _user_errors() as exc:
        raise CliError(str(exc)) from exc
    gt = ground_truth_error(body, shape, inputs)
    print(f"wrote {args.output / 'shape.npz'} and {args.output / 'canonical.obj'}: "
          f"{len(shape.frames)} key-frames, {shape.seconds:.1f} s for the last shape fit"
          + (f"; surface error against the ground truth {gt['surface_error_mm']:.2f} mm"
             if gt else ""))  # fmt: skip
    return 0


def _add_animate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "animate",
        help="re-pose an avatar with a built-in motion or another video's poses (animated glb)",
        description="Write the avatar of a 'monoavatar reconstruct' folder as an animated "
        "glTF 2.0 binary: a built-in motion (walk, wave) or the poses of another params.npz.",
    )
    p.add_argument("avatar", type=Path, help="a folder written by 'monoavatar reconstruct'")
    p.add_argument("-o", "--output", required=True, type=Path, help="the .glb to write")
    p.add_argument("--motion", default="walk",
                   help="walk (default), wave, or a path to a params.npz / poses.npz")  # fmt: skip
    p.add_argument("--frames", type=int, default=None, help="frames of a built-in motion")
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.set_defaults(run=_run_animate)


def _run_animate(args: argparse.Namespace) -> int:
    from monoavatar.animate import animate_folder

    try:
        path = animate_folder(args.avatar, args.motion, args.output, frames=args.frames,
                              fps=args.fps)  # fmt: skip
    except (OSError, ValueError) as exc:
        raise CliError(str(exc)) from exc
    print(f"wrote {path}")
    return 0


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="synthesise a short turn-around video and reconstruct an avatar from it",
        description="The embedded default: render a synthetic person turning around "
        "(monoavatar synth turnaround), reconstruct an avatar from the rendered video with "
        "mediapipe perception, and print its surface error against the ground truth.",
    )
    p.add_argument("-o", "--output", required=True, type=Path, help="output folder")
    p.add_argument("--frames", type=int, default=60, help="frames of the video (default 60)")
    p.add_argument("--seed", type=int, default=3, help="subject and scene seed (default 3)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    from monoavatar.reconstruct import ReconstructConfig, reconstruct
    from monoavatar.synth.scene import SynthConfig, SynthError, generate

    scene = args.output / "input"
    try:
        if not (scene / "scene.json").is_file():
            generate(scene, SynthConfig(kind="turnaround", frames=args.frames, seed=args.seed),
                     progress=not args.quiet)  # fmt: skip
        config = ReconstructConfig(frames=args.frames, perception="mediapipe",
                                   progress=not args.quiet)  # fmt: skip
        result = reconstruct(scene, args.output / "avatar",
                             config)  # fmt: skip
    except SynthError as exc:
        raise CliError(str(exc)) from exc
    except _user_errors() as exc:
        raise CliError(str(exc)) from exc
    print(f"input video: {scene / 'video.mp4'} (ground truth in {scene / 'gt'})")
    _print_summary(result.report, result.out_dir)
    return 0


def _add_bench(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="measure accuracy and speed on a fixed synthetic suite, beside the dissertation",
        description="Generate the fixed, versioned suite of synthetic turn-around subjects "
        "(minimal clothing and clothed, from fixed seeds; cached in OUT/scenes), reconstruct "
        "each with mediapipe perception and fitted poses, and with ground-truth poses, and "
        "write results.json, results.md (a table beside Table B.1 of the dissertation) and "
        "per-vertex error heat maps. The texture PSNR poses each finished avatar in frames "
        "it was not built from with our tracker (the key-frames' poses interpolated, then "
        "flow rounds on those frames). The full suite takes about 35 minutes on 2 CPU cores.",
    )
    p.add_argument("-o", "--output", type=Path, default=Path("out/bench"),
                   help="output folder (default out/bench)")  # fmt: skip
    p.add_argument("--quick", action="store_true",
                   help="one small subject with few frames: a smoke test of a few minutes")
    p.add_argument("--subjects", nargs="+", default=None, metavar="NAME",
                   help="run only these suite subjects")  # fmt: skip
    p.add_argument("--no-gt-poses", action="store_true",
                   help="skip the runs with ground-truth poses")  # fmt: skip
    p.add_argument("--measure-only", action="store_true",
                   help="reconstruct nothing: measure the runs an earlier benchmark left in "
                   "OUT/runs again (after the metrics changed); times are those the runs "
                   "reported")  # fmt: skip
    p.add_argument("--track-rounds", type=int, default=3, metavar="N",
                   help="flow rounds of the tracker that poses the avatar in the held-out "
                   "frames for the texture PSNR (default 3; 0: the key-frames' poses "
                   "interpolated)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_run_bench)


def _run_bench(args: argparse.Namespace) -> int:
    from monoavatar.bench.runner import run_bench
    from monoavatar.bench.suite import SuiteError

    if args.track_rounds < 0:
        raise CliError(f"--track-rounds must be >= 0, got {args.track_rounds}")
    try:
        run_bench(args.output, quick=args.quick, subjects=args.subjects,
                  gt_poses=not args.no_gt_poses, progress=not args.quiet,
                  measure_only=args.measure_only, track_rounds=args.track_rounds)  # fmt: skip
    except SuiteError as exc:
        raise CliError(str(exc)) from exc
    except _user_errors() as exc:
        raise CliError(str(exc)) from exc
    print(f"results: {args.output / 'results.md'} and {args.output / 'results.json'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="monoavatar",
        description="Animatable, textured 3D avatars and 3D motion from monocular video.",
    )
    parser.add_argument("--version", action="version", version=f"monoavatar {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo(sub)
    _add_reconstruct(sub)
    _add_fit_poses(sub)
    _add_fit_shape(sub)
    _add_animate(sub)
    _add_bench(sub)
    _add_synth(sub)
    _add_body(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(args.run(args))
    except CliError as exc:
        print(f"monoavatar {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
