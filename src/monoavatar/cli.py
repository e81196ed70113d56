"""The ``monoavatar`` command line."""

from __future__ import annotations

import argparse
import sys

from monoavatar import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="monoavatar",
        description="Animatable, textured 3D avatars and 3D motion from monocular video.",
    )
    parser.add_argument("--version", action="version", version=f"monoavatar {__version__}")
    parser.add_subparsers(dest="command", metavar="COMMAND")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
