"""The ``monoavatar`` command line: one sub-command per capability."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from monoavatar import __version__


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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="monoavatar",
        description="Animatable, textured 3D avatars and 3D motion from monocular video.",
    )
    parser.add_argument("--version", action="version", version=f"monoavatar {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
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
