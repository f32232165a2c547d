"""Command line: ``python -m taichi_cloth COMMAND ...``. Parses arguments and dispatches."""

import argparse
import sys

from .errors import InputError, UnstableError


class ArgumentParser(argparse.ArgumentParser):
    """argparse that reports bad flags as one line with exit code 2 (DESIGN.md)."""

    def error(self, message):
        sys.stderr.write(f"{self.prog}: {message}\n")
        raise SystemExit(2)


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE",
                        help="a scene name in scenes/ (e.g. hula) or a path to a .toml file")
    parser.add_argument("--frames", type=int, help="number of frames (default: duration × fps)")
    parser.add_argument("--out", help="output folder (default: output/<scene>)")
    parser.add_argument("--arch", choices=("cpu", "cuda", "vulkan", "gpu"),
                        help="Taichi backend (default: the scene's simulation.arch)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a dotted scene key with a TOML value, e.g. "
                             "--set simulation.integrator=rk4 (repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no progress or summary")


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m taichi_cloth",
                            description="Mass-spring cloth on a dancing capsule body, in Taichi.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=ArgumentParser)
    simulate = commands.add_parser("simulate", help="physics only; writes stats.json")
    add_scene_arguments(simulate)
    commands.add_parser("scenes", help="list the shipped scenes")
    commands.add_parser("materials", help="list the fabric presets")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from . import commands
    try:
        if args.command == "simulate":
            return commands.simulate(args.scene, args.overrides, args.frames, args.out,
                                     args.arch, args.quiet)
        if args.command == "scenes":
            return commands.list_scenes()
        if args.command == "materials":
            return commands.list_materials()
    except (InputError, UnstableError) as error:
        sys.stderr.write(f"error: {error}\n")
        return error.exit_code
    return 1


if __name__ == "__main__":
    sys.exit(main())
