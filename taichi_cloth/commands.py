"""What each command-line command does; ``__main__`` only parses arguments and calls these."""

import os
from pathlib import Path

from .errors import InputError
from .export import write_json
from .materials import PRESETS
from .scene import Scene, load_scene, shipped_scene_names

OUTPUT_ROOT = Path("output")


def prepare_scene(scene_name: str, overrides: list[str], frames: int | None, arch: str | None):
    """Load the scene with the common flags applied."""
    extra = list(overrides or [])
    if arch is not None:
        extra.append(f"simulation.arch={arch}")
    scene = load_scene(scene_name, tuple(extra))
    if frames is not None and frames < 1:
        raise InputError(f"--frames {frames}: must be at least 1")
    return scene, frames if frames is not None else scene.frame_count


def output_dir(scene: Scene, out: str | None) -> Path:
    """--out, else [output].dir, else output/<scene>."""
    if out:
        return Path(out)
    if scene.output.dir:
        return Path(scene.output.dir)
    return OUTPUT_ROOT / scene.name


def check_writable(directory: Path, flag: str) -> None:
    """Fail early, before simulating, if ``directory`` cannot be created or written."""
    existing = directory
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{flag} {directory}: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{flag} {directory}: not writable")


def make_body_rig(scene: Scene):
    """The body rig of a scene with a [body] section (None otherwise)."""
    if scene.body is None:
        return None
    from .rig import BodyRig
    return BodyRig(scene)


def simulate(scene_name: str, overrides: list[str], frames: int | None, out: str | None,
             arch: str | None, quiet: bool) -> int:
    """Physics only: run the scene and write stats.json."""
    from .simulation import Simulation
    scene, frame_count = prepare_scene(scene_name, overrides, frames, arch)
    directory = output_dir(scene, out)
    check_writable(directory, "--out")
    simulation = Simulation(scene, make_body_rig(scene))
    record = simulation.run(frame_count)
    stats = simulation.stats(record)
    write_json(directory / "stats.json", stats)
    if not quiet:
        print(f"{scene.name}: {len(record.frames)} frames, {stats['integrator']} at dt = "
              f"{stats['dt']:.6g} s ({stats['substeps_per_frame']} substeps/frame), "
              f"max strain {stats['max_strain']:.4f}, max penetration "
              f"{stats['max_penetration'] * 1000:.2f} mm, compile "
              f"{stats['wall_seconds']['compile']:.2f} s, simulate "
              f"{stats['wall_seconds']['simulate']:.2f} s → {directory / 'stats.json'}")
    return 0


def list_scenes() -> int:
    for name in shipped_scene_names():
        scene = load_scene(name)
        print(f"{name:12s} {scene.scene.description}")
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
