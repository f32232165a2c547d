"""Command line: ``python -m taichi_cloth COMMAND ...``. Parses arguments, loads the scene,
and hands it to the command's module: ``output.run`` (simulate, render), ``studies.compare``,
``studies.bench``; lists what ships."""

import argparse
import math
import signal
import sys
from pathlib import Path

import numpy as np

from taichi_cloth.config.materials import PRESETS
from taichi_cloth.config.scene import (SCENES_DIR, arch_override, load_scene,
                                       refuse_lab_specimen, resolved_document,
                                       shipped_scene_names)
from taichi_cloth.config.tables import MESH_FORMATS
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.flags import choice_list
from taichi_cloth.output.budget import RunLimits
from taichi_cloth.output.files import PATH_ERRORS, file_system_message
from taichi_cloth.output.run import CONSOLE_SCRIPT
from taichi_cloth.runtime import ARCH_NAMES


class ArgumentParser(argparse.ArgumentParser):
    """argparse that reports bad flags as one line with exit code 2 (README, "Exit codes")."""

    def error(self, message):
        sys.stderr.write(f"{self.prog}: {message}\n")
        raise SystemExit(2)


def add_common_arguments(parser: argparse.ArgumentParser, out_help: str, set_help: str) -> None:
    """--out, --arch, --set and --quiet, shared by the commands that run a scene."""
    parser.add_argument("--out", help=out_help)
    parser.add_argument("--arch", choices=ARCH_NAMES,
                        help="Taichi backend (default: the scene's simulation.arch)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help=set_help)
    parser.add_argument("--quiet", action="store_true", help="no progress or summary")


def add_scene_arguments(parser: argparse.ArgumentParser, optional_scene: bool = False) -> None:
    parser.add_argument("scene", metavar="SCENE", nargs="?" if optional_scene else None,
                        help="a scene name in scenes/ (e.g. hula) or a path to a .toml file")
    parser.add_argument("--frames", type=int, help="number of frames (default: duration × fps)")
    add_common_arguments(parser, "output folder (default: output/<scene>)",
                         "override a dotted scene key with a TOML value, e.g. "
                         "--set simulation.integrator=rk4 (repeatable)")
    parser.add_argument("--resume", action="store_true",
                        help="continue an interrupted run from the checkpoint in its output folder")
    parser.add_argument("--max-hours", type=float, default=RunLimits.max_hours, metavar="H",
                        help="refuse (exit 2) a run estimated to take longer than H hours "
                             f"(default {RunLimits.max_hours:g})")
    parser.add_argument("--max-memory", type=float, metavar="GB",
                        help="refuse (exit 2) a cloth that needs more memory than GB (default: "
                             "80 %% of the memory available)")


def mesh_formats(text: str) -> tuple[str, ...]:
    """--meshes: a comma list of mesh formats."""
    try:
        return choice_list(text, "--meshes", MESH_FORMATS, "mesh format")
    except InputError as error:
        raise argparse.ArgumentTypeError(str(error).removeprefix(f"--meshes {text}: ")) from None


def add_mesh_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--meshes", type=mesh_formats, metavar="LIST",
                        help=f"cloth meshes per frame, a comma list of {','.join(MESH_FORMATS)} "
                             "(obj/ply/vtu: one file per frame; xdmf: one time series; usd: "
                             "one stage with the body, needs usd-core; pc2: a point cache "
                             "beside an OBJ, for Blender's Mesh Cache) under meshes/ (default: "
                             "the scene's output.meshes)")
    parser.add_argument("--body-meshes", action="store_true",
                        help="also write the body's capsules as meshes")


def add_compare_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE",
                        help="a scene name in scenes/ (e.g. sheet) or a path to a .toml file")
    parser.add_argument("--integrators", metavar="LIST",
                        help="comma list of euler,symplectic,rk4,implicit (default: all)")
    parser.add_argument("--dts", metavar="LIST",
                        help="comma list of time steps [s], each rounded down to divide the "
                             "frame time (default: a geometric series spanning every "
                             "integrator's stability limit)")
    parser.add_argument("--duration", metavar="T",
                        help="simulated seconds per run (default: the scene's, at most 1 s)")
    parser.add_argument("--reference-dt", metavar="DT",
                        help="step [s] of the RK4 double-precision reference (default: the "
                             "smallest swept step / 4)")
    parser.add_argument("--video-dt", metavar="DT",
                        help="step [s] of the side-by-side video (default: the largest swept "
                             "step at which every integrator stayed stable)")
    parser.add_argument("--no-video", action="store_true",
                        help="skip the side-by-side video and contact sheet (they need Vulkan)")
    add_common_arguments(parser, "output folder (default: output/compare/<scene>)",
                         "override a dotted scene key with a TOML value (repeatable); runs are "
                         "in f64 unless --set simulation.precision=f32")


def add_executor_arguments(parser: argparse.ArgumentParser, default_workers: str) -> None:
    """--workers and --cluster: where a batch of runs executes (studies/executors.py)."""
    parser.add_argument("--workers", type=int, metavar="N",
                        help=f"run N simulations side by side in local worker processes, one "
                             f"Taichi thread each (1: in this process; default {default_workers})")
    parser.add_argument("--cluster", metavar="ADDRESS",
                        help="run on the Dask cluster whose scheduler is at ADDRESS (e.g. "
                             "tcp://10.0.0.5:8786; needs the cluster extra, docs/scaling.md)")


def add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE", nargs="?",
                        help="a scene name in scenes/ or a path to a .toml file (or --plan)")
    parser.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                        help="a scene key and its values, e.g. --grid cloth.material=silk,cotton "
                             "(repeatable: every combination runs)")
    parser.add_argument("--plan", metavar="FILE",
                        help="a TOML file whose [sweep] table gives scene, set, frames and grid")
    parser.add_argument("--frames", type=int, help="frames per run (default: the scene's)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the sweep in --out: runs already finished are kept")
    parser.add_argument("--out", help="output folder (default: output/sweep/<scene>)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="override a scene key in every run "
                                                  "(repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no progress or summary")
    add_executor_arguments(parser, "the usable cores")


def build_parser() -> argparse.ArgumentParser:
    console = Path(sys.argv[0]).name == CONSOLE_SCRIPT
    parser = ArgumentParser(prog=CONSOLE_SCRIPT if console else "python -m taichi_cloth",
                            description="Mass-spring cloth on a dancing capsule body, in Taichi.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=ArgumentParser)
    simulate = commands.add_parser("simulate", help="physics only; writes stats.json")
    add_scene_arguments(simulate)
    add_mesh_arguments(simulate)
    render = commands.add_parser("render", help="simulate and write PNG frames (headless GGUI), "
                                                "a video and meshes when asked")
    add_scene_arguments(render, optional_scene=True)
    render.add_argument("--from-cache", metavar="DIR",
                        help="draw the frames (and --video) of the run cached in DIR/cache "
                             "instead of simulating (no SCENE; --out defaults to DIR)")
    render.add_argument("--width", type=int, help="frame width in pixels (default: render.width)")
    render.add_argument("--height", type=int,
                        help="frame height in pixels (default: render.height)")
    render.add_argument("--video", choices=("mp4", "gif"),
                        help="also write <scene>.mp4 (H.264) or .gif at the scene's fps")
    add_mesh_arguments(render)
    compare = commands.add_parser(
        "compare", help="every integrator on one scene: error against a reference vs cost, "
                        "table, CSV, plots, side-by-side video")
    add_compare_arguments(compare)
    add_executor_arguments(compare, "1")
    view = commands.add_parser("view", help="an interactive window playing the scene (live) or "
                                            "a cached run: play, pause, step, orbit, toggles")
    view.add_argument("scene", metavar="SCENE", nargs="?",
                      help="a scene name in scenes/ or a path to a .toml file")
    view.add_argument("--from-cache", metavar="DIR", help="play the run cached in DIR/cache")
    view.add_argument("--set", dest="overrides", action="append", default=[],
                      metavar="KEY=VALUE", help="override a dotted scene key (repeatable)")
    view.add_argument("--width", type=int, help="window width in pixels (default render.width)")
    view.add_argument("--height", type=int, help="window height (default render.height)")
    view.add_argument("--frames", type=int,
                      help="play N frames, then stop (with --screenshot: for scripts)")
    view.add_argument("--screenshot", metavar="PNG", help="save the last frame shown to PNG")
    view.add_argument("--quiet", action="store_true", help="no status lines")
    sweep = commands.add_parser(
        "sweep", help="many runs of a scene over a grid of --set values, locally or on a Dask "
                      "cluster: a folder per run, a table and a contact sheet (docs/scaling.md)")
    add_sweep_arguments(sweep)
    show = commands.add_parser("show", help="print a scene as resolved (every key with its "
                                            "default, the preset's fabric values, --set "
                                            "applied) as TOML")
    show.add_argument("scene", metavar="SCENE",
                      help="a scene name in scenes/ (e.g. hula) or a path to a .toml file")
    show.add_argument("--set", dest="overrides", action="append", default=[],
                      metavar="KEY=VALUE", help="override a dotted scene key with a TOML value")
    commands.add_parser("scenes", help="list the shipped scenes, the hard cases (hard/...) and "
                                       "the textile lab's specimens (lab/...)")
    commands.add_parser("materials", help="list the fabric presets")
    bench = commands.add_parser(
        "bench", help="substep throughput: the reference sheet per size and integrator, a NumPy "
                      "baseline, real scenes with every integrator and their whole runs, each "
                      "effect's cost (docs/performance.md)")
    bench.add_argument("--sizes", metavar="LIST",
                       help="reference sheet sizes n (n × n particles), e.g. 32,64,128,256 "
                            "(alone: only the sizes table)")
    bench.add_argument("--integrators", metavar="LIST",
                       help="comma list of integrators for the sizes table and, with "
                            "--scene, the scenes' integrator rows (default: symplectic,euler,"
                            "rk4,implicit)")
    bench.add_argument("--scene", metavar="LIST",
                       help="comma list of scenes: every integrator, the whole run, the effect "
                            "costs and passes (default: hula, hula-paper, flag, drape, the "
                            "effects of hula only; alone: only those parts)")
    bench.add_argument("--json", metavar="FILE", help="also write the rows as JSON to FILE")
    bench.add_argument("--seconds", type=float, default=1.0,
                       help="minimum seconds per timed repeat (default 1)")
    bench.add_argument("--repeats", type=int, default=3,
                       help="timed repeats per figure, the median is reported (default 3)")
    bench.add_argument("--arch", choices=ARCH_NAMES, default="cpu",
                       help="Taichi backend (default cpu)")
    bench.add_argument("--threads", type=int, metavar="N",
                       help="CPU threads for Taichi (default: one per core of the machine; with "
                            "taskset -c on N cores, the figures of an N-core machine)")
    bench.add_argument("--quiet", action="store_true", help="no progress lines")
    fabric = commands.add_parser(
        "fabric-test", help="the virtual textile lab: the cantilever bending test (ASTM D1388) "
                            "or the Cusick drape test on a fabric (docs/fabric-tests.md)")
    fabric.add_argument("test", choices=("cantilever", "drape"))
    fabric.add_argument("--material", default="cotton", metavar="LIST",
                        help="comma list of fabric presets or scene files whose "
                             "[cloth.material] to test (default cotton)")
    fabric.add_argument("--resolution", default="0.5", metavar="LIST",
                        help="particle spacing as a fraction of the bending length (the "
                             "drape: of at most 2 cm, a third of the overhang), a comma list "
                             "(default 0.5)")
    fabric.add_argument("--specimens", type=int, default=3,
                        help="drape: specimens per material and resolution, each from its own "
                             "start ripple; their mean DC is reported (default 3, as ISO 9073-9)")
    add_common_arguments(fabric, "output folder (default: output/fabric-test/<test>)",
                         "override a dotted key of the lab scene (scenes/lab/<test>.toml), "
                         "e.g. --set cloth.material.bend_stiffness=2e-5 (repeatable)")
    bench.add_argument("--profile", action="store_true",
                       help="also print Taichi's kernel profiler table (time per kernel; the "
                            "profiler's own timing slows the rates, so read them from a run "
                            "without it)")
    return parser


def prepare_scene(scene_name: str, overrides: list[str], frames: int | None, arch: str | None):
    """Load the scene with the common flags applied (not a textile lab specimen:
    ``refuse_lab_specimen``)."""
    refuse_lab_specimen(scene_name)
    extra, flags = arch_override(overrides, arch)
    scene = load_scene(scene_name, tuple(extra), flags)
    if frames is not None and frames < 1:
        raise InputError(f"--frames {frames}: must be at least 1")
    return scene, frames if frames is not None else scene.frame_count


def check_size(value: int, flag: str) -> None:
    """--width/--height: the renderer's pixel range."""
    if not 16 <= value <= 8192:
        raise InputError(f"{flag} {value}: must be between 16 and 8192 pixels")


def simulate(scene_name: str, overrides: list[str], frames: int | None, out: str | None,
             arch: str | None, quiet: bool, meshes=None, body_meshes: bool = False,
             resume: bool = False, limits: RunLimits = RunLimits()) -> int:
    """Physics only: run the scene and write stats.json (and meshes when asked)."""
    from taichi_cloth.output.run import output_dir, run_scene
    scene, frame_count = prepare_scene(scene_name, overrides, frames, arch)
    return run_scene(scene, frame_count, output_dir(scene, out), quiet,
                     meshes=scene.output.meshes if meshes is None else meshes,
                     body_meshes=body_meshes or scene.output.body_meshes, resume=resume,
                     limits=limits)


def render(scene_name: str, overrides: list[str], frames: int | None, out: str | None,
           arch: str | None, quiet: bool, width: int | None = None, height: int | None = None,
           video: str | None = None, meshes=None, body_meshes: bool = False,
           resume: bool = False, limits: RunLimits = RunLimits()) -> int:
    """Simulate and write PNG frames (headless GGUI), and a video and meshes when asked."""
    from taichi_cloth.output.run import output_dir, run_scene
    for value, flag in ((width, "--width"), (height, "--height")):
        if value is not None:
            check_size(value, flag)
    scene, frame_count = prepare_scene(scene_name, overrides, frames, arch)
    size = (width or scene.render.width, height or scene.render.height)
    return run_scene(scene, frame_count, output_dir(scene, out), quiet, size,
                     video=scene.output.video if video is None else video,
                     meshes=scene.output.meshes if meshes is None else meshes,
                     body_meshes=body_meshes or scene.output.body_meshes, resume=resume,
                     limits=limits)


def list_scenes() -> int:
    """Every shipped scene with its description: the top-level ones, then each folder's
    (``hard/``: the hard cases, ``lab/``: the textile lab's specimens), by the name that loads
    them."""
    names = shipped_scene_names() + sorted(
        path.relative_to(SCENES_DIR).with_suffix("").as_posix()
        for path in SCENES_DIR.glob("*/*.toml"))
    width = max(len(name) for name in names) + 2
    for name in names:
        print(f"{name:{width}s}{load_scene(name).scene.description}")
    return 0


def list_materials() -> int:
    print(f"{'name':10s} {'density':>9s} {'stretch':>9s} {'shear':>7s} {'bend':>9s} "
          f"{'damping':>8s} {'thick':>6s}")
    print(f"{'':10s} {'kg/m²':>9s} {'N/m':>9s} {'N/m':>7s} {'N·m':>9s} {'s':>8s} {'mm':>6s}")
    for material in PRESETS.values():
        print(f"{material.name:10s} {material.density:9.3f} {material.stretch_stiffness:9.0f} "
              f"{material.shear_stiffness:7.1f} {material.bend_stiffness:9.2e} "
              f"{material.damping:8.1e} {material.thickness * 1000:6.2f}  {material.description}")
    return 0


def render_cached(args) -> int:
    """``render --from-cache DIR``: the cached run's frames drawn again (output/replay.py)."""
    from taichi_cloth.output.replay import render_from_cache
    given = [flag for flag, value in (("SCENE", args.scene), ("--set", args.overrides),
                                      ("--frames", args.frames), ("--resume", args.resume),
                                      ("--arch", args.arch))
             if value]
    if given:
        raise InputError(f"--from-cache: draws the cached run as it was; {', '.join(given)} "
                         f"cannot change it")
    for value, flag in ((args.width, "--width"), (args.height, "--height")):
        if value is not None:
            check_size(value, flag)
    return render_from_cache(Path(args.from_cache), Path(args.out) if args.out else None,
                             (args.width, args.height), args.video, args.quiet,
                             args.meshes or (), args.body_meshes)


def view_command(args) -> int:
    """``view SCENE`` or ``view --from-cache DIR`` (output/view.py)."""
    from taichi_cloth.output.view import view
    for value, flag in ((args.width, "--width"), (args.height, "--height")):
        if value is not None:
            check_size(value, flag)
    if (args.scene is None) == (args.from_cache is None):
        raise InputError("view: give a SCENE or --from-cache DIR (one of the two)")
    if args.from_cache is not None and args.overrides:
        raise InputError("--from-cache: plays the cached run as it was; --set cannot change it")
    scene = load_scene(args.scene, tuple(args.overrides)) if args.scene is not None else None
    return view(scene, args.from_cache, (args.width, args.height), args.frames, args.screenshot,
                args.quiet)


def run_limits(args) -> RunLimits:
    """--max-hours and --max-memory, checked."""
    if not (args.max_hours > 0 and math.isfinite(args.max_hours)):
        raise InputError(f"--max-hours {args.max_hours}: must be a positive number of hours")
    if args.max_memory is not None and not (args.max_memory > 0 and
                                            math.isfinite(args.max_memory)):
        raise InputError(f"--max-memory {args.max_memory}: must be a positive number of GB")
    return RunLimits(args.max_hours, args.max_memory)


def stop_on_terminate(signum, frame):
    """SIGTERM unwinds like Ctrl-C, so half-written outputs are removed (exit 128 + 15)."""
    raise SystemExit(128 + signum)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    signal.signal(signal.SIGTERM, stop_on_terminate)
    with np.errstate(all="ignore"):  # bad numbers end in one line of their own, not warnings
        return run_command(args)


def run_command(args) -> int:
    """The command ``args`` names, its errors turned into one line and an exit code."""
    try:
        if args.command == "simulate":
            return simulate(args.scene, args.overrides, args.frames, args.out,
                            args.arch, args.quiet, args.meshes, args.body_meshes,
                            args.resume, run_limits(args))
        if args.command == "render" and args.from_cache is not None:
            return render_cached(args)
        if args.command == "render":
            if args.scene is None:
                raise InputError("render: needs a SCENE, or --from-cache DIR")
            return render(args.scene, args.overrides, args.frames, args.out, args.arch,
                          args.quiet, args.width, args.height, args.video, args.meshes,
                          args.body_meshes, args.resume, run_limits(args))
        if args.command == "compare":
            from taichi_cloth.studies.compare import compare
            return compare(args.scene, args.overrides, args.integrators, args.dts, args.duration,
                           args.out, args.arch, args.quiet, args.reference_dt, args.video_dt,
                           not args.no_video, args.workers, args.cluster)
        if args.command == "view":
            return view_command(args)
        if args.command == "sweep":
            from taichi_cloth.studies.sweep import sweep
            return sweep(args.scene, args.grid, args.overrides, args.frames, args.out,
                         args.workers, args.cluster, args.resume, args.plan, args.quiet)
        if args.command == "bench":
            from taichi_cloth.studies.bench import bench_command
            return bench_command(args.sizes, args.integrators, args.scene, args.json,
                                 args.seconds, args.repeats, args.arch, args.quiet, args.profile,
                                 args.threads)
        if args.command == "fabric-test":
            from taichi_cloth.studies.fabric_lab import fabric_test_command
            arch = [f"simulation.arch={args.arch}"] if args.arch else []
            return fabric_test_command(args.test, args.material, args.resolution,
                                       args.overrides + arch, args.out, args.quiet,
                                       args.specimens)
        if args.command == "scenes":
            return list_scenes()
        if args.command == "show":
            import tomli_w
            scene = load_scene(args.scene, tuple(args.overrides))
            sys.stdout.write(f"# {scene.path}, resolved\n{tomli_w.dumps(resolved_document(scene))}")
            return 0
        if args.command == "materials":
            return list_materials()
    except (InputError, UnstableError) as error:
        sys.stderr.write(f"error: {' '.join(str(error).split())}\n")  # one line, whatever
        return error.exit_code
    except KeyboardInterrupt:
        sys.stderr.write("interrupted; the files written so far are whole\n")
        return 130
    except OSError as error:  # the file system said no: one line, no traceback
        sys.stderr.write(f"error: {file_system_message(error)}\n")
        return 2 if error.errno in PATH_ERRORS else 1
    return 1
