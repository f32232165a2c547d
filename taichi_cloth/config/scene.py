"""Scene files: TOML plus ``--set`` overrides into a frozen, validated ``Scene``.

Every key of every section is declared once, in the dataclasses of ``config.tables`` (and each
effect's table in its own ``Settings``, ``effects/``), with its default and its check (``settings.setting``).
``load_scene`` parses the file with ``tomllib``, applies the overrides, and
walks the tables against those declarations: an unknown key (with the closest valid one
suggested), a wrong type or an impossible value raises ``InputError`` naming the file (or the
``--set`` flag) and the dotted key. Units are SI, angles in degrees, y is up.
"""

import copy
import dataclasses
import difflib
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from taichi_cloth.config.materials import Material
from taichi_cloth.config.tables import (BodyConfig, ClothConfig, OutputConfig, RenderConfig,
                                        SceneInfo, SimulationConfig)
from taichi_cloth.effects import EFFECT_BY_NAME
from taichi_cloth.errors import InputError
from taichi_cloth.settings import SourceContext, build_table, numbers_in

# The shipped scenes: the repository's top-level scenes/ (taichi_cloth/scenes links to it, and an
# installed package carries the files there: pyproject.toml)
SCENES_DIR = (Path(__file__).parents[1] / "scenes").resolve()
LAB_SCENES = SCENES_DIR / "lab"  # the textile lab's specimens, run by ``fabric-test``


@dataclass(frozen=True)
class Scene:
    """A whole validated scene. ``effects`` maps each declared effect name to its settings, in
    a fixed order; an effect that is absent is not compiled (README: only the effects a scene declares)."""

    path: str
    scene: SceneInfo
    simulation: SimulationConfig
    cloth: ClothConfig
    effects: dict
    body: BodyConfig | None
    render: RenderConfig
    output: OutputConfig
    document: dict = dataclasses.field(default_factory=dict, compare=False)  # the TOML tables
    # after the overrides, from which ``scene_from_document`` builds this scene again

    @property
    def name(self) -> str:
        return self.scene.name

    @property
    def material(self) -> Material:
        return self.cloth.material.resolve()

    @property
    def frame_count(self) -> int:
        return max(1, round(self.scene.duration * self.scene.fps))


# ---------------------------------------------------------------------------------------------
# Parsing and overrides


def resolve_scene_path(name_or_path: str) -> Path:
    """A scene name in ``scenes/`` or a path to a ``.toml`` file."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml" or candidate.exists():
        if not candidate.is_file():
            raise InputError(f"{name_or_path}: scene file not found")
        return candidate
    shipped = SCENES_DIR / f"{name_or_path}.toml"
    if shipped.is_file():
        return shipped
    names = ", ".join(shipped_scene_names())
    raise InputError(f"{name_or_path}: no such scene (shipped scenes: {names}; or give a .toml path)")


def shipped_scene_names() -> list[str]:
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def parse_override(text: str) -> tuple[list[str], Any]:
    """``KEY=VALUE`` → (dotted key parts, value). VALUE is TOML; a bare word that is not valid
    TOML is a string (README, "Commands")."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise InputError(f"--set {text}: expected KEY=VALUE with a dotted key, e.g. "
                         f"--set simulation.integrator=rk4")
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        if not raw or any(c in raw for c in "[]{}\"'=,"):
            raise InputError(f"--set {text}: value {raw!r} is not a valid TOML value") from None
        value = raw
    return key.split("."), value


def apply_override(raw: dict, parts: list[str], value: Any) -> None:
    """Set a dotted key in the raw TOML tree, creating tables on the way.

    ``cloth.material`` may be a preset name or a table; setting a key below a name turns it into
    ``{preset = name, ...}``. ``effects.X = false`` removes effect X, ``true`` declares it with
    its defaults.
    """
    node = raw
    for depth, part in enumerate(parts[:-1]):
        child = node.get(part)
        if isinstance(child, str) and parts[:depth + 1] == ["cloth", "material"]:
            child = {"preset": child}
        elif child is None or child is True:
            child = {}
        elif not isinstance(child, dict):
            dotted = ".".join(parts[:depth + 1])
            raise InputError(f"--set {'.'.join(parts)}: {dotted} is not a table")
        node[part] = child
        node = child
    node[parts[-1]] = value


def _build_effects(ctx: SourceContext, table: Any, bending: str) -> dict:
    """The declared effects, name → settings, in ``EFFECTS`` order; curvature bending
    (``cloth.bending = "curvature"``) is declared with its defaults unless [effects.bending]
    gives its settings (``effects.bending = false`` leaves it out, as ``cloth.bending = "none"``)."""
    if not isinstance(table, dict):
        raise ctx.error("effects", f"expected a table of effects, got {table!r}")
    effects = {}
    for name, settings in table.items():
        if name not in EFFECT_BY_NAME:
            close = difflib.get_close_matches(name, list(EFFECT_BY_NAME), n=1)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise ctx.error(f"effects.{name}", f"unknown effect '{name}'; {hint}valid: "
                                               f"{', '.join(EFFECT_BY_NAME)}")
        if settings is False:
            continue
        if settings is True:
            settings = {}
        effects[name] = build_table(ctx, EFFECT_BY_NAME[name].Settings, settings,
                                    f"effects.{name}")
    if bending == "curvature" and table.get("bending") is not False:
        effects.setdefault("bending", EFFECT_BY_NAME["bending"].Settings())
    elif "bending" in effects:
        raise ctx.error("effects.bending", f"needs cloth.bending = \"curvature\", got "
                                           f"{bending!r}")
    return {name: effects[name] for name in EFFECT_BY_NAME if name in effects}


SECTIONS = ("scene", "simulation", "cloth", "effects", "body", "render", "output")


def load_scene(name_or_path: str, overrides: tuple[str, ...] = (),
               flags: dict[str, str] | None = None) -> Scene:
    """Read, override and validate a scene. ``flags``: the flag an override text stands for
    (e.g. "simulation.arch=cuda" → "--arch cuda"), named in its errors instead of "--set KEY".
    Raises ``InputError`` on any bad input."""
    path = resolve_scene_path(name_or_path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"{path}: not valid TOML: {error}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read: {error}") from None
    overridden = {}
    for text in overrides:
        parts, value = parse_override(text)
        apply_override(raw, parts, value)
        key = ".".join(parts)
        overridden[key] = (flags or {}).get(text, f"--set {key}")
    return scene_from_document(path, raw, overridden)


def refuse_lab_specimen(name_or_path: str) -> None:
    """``InputError`` for a scene of ``LAB_SCENES``: the textile lab's specimens step 0.5 s at a
    time, Newton steps from rest that ``fabric-test`` takes; run frame by frame (``simulate``,
    ``render``, ``compare``, ``sweep``, ``bench``) they blow up in their first frame."""
    path = resolve_scene_path(name_or_path).resolve()
    if path.parent == LAB_SCENES:
        raise InputError(f"{name_or_path}: a textile lab specimen, brought to rest by "
                         f"`fabric-test {path.stem}`, not simulated frame by frame")


def arch_override(overrides, arch: str | None) -> tuple[list[str], dict[str, str]]:
    """The --set overrides with --arch as one more (``simulation.arch``), and the flags to name
    in its errors (``load_scene``)."""
    extra = list(overrides or [])
    if arch is None:
        return extra, {}
    text = f"simulation.arch={arch}"
    return [*extra, text], {text: f"--arch {arch}"}


def scene_from_document(path: Path, raw: dict, overridden: dict[str, str] | None = None) -> Scene:
    """The validated scene of a TOML document ``raw`` (the file's tables after the overrides
    ``overridden``: dotted key → the flag that set it) read from ``path`` (relative paths in it,
    such as a texture's, are relative to that file). Raises ``InputError`` on any bad input."""
    path = Path(path)
    ctx = SourceContext(str(path), dict(overridden or {}))
    for section in raw:
        if section not in SECTIONS:
            close = difflib.get_close_matches(section, SECTIONS, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else f"; valid: {', '.join(SECTIONS)}"
            raise ctx.error(section, f"unknown section [{section}]{hint}")
    info = build_table(ctx, SceneInfo, raw.get("scene", {}), "scene")
    if not info.name:
        info = dataclasses.replace(info, name=path.stem)
    raw_springs = raw.get("cloth", {}).get("springs", []) if isinstance(raw.get("cloth"), dict) \
        else []
    if isinstance(raw_springs, list) and "bend" in raw_springs:
        raise ctx.error("cloth.springs", "skip-one \"bend\" springs are chosen with "
                                         "cloth.bending = \"springs\"")
    cloth = build_table(ctx, ClothConfig, raw.get("cloth", {}), "cloth")
    body = build_table(ctx, BodyConfig, raw["body"], "body") if "body" in raw else None
    if cloth.pin == "waist" and not cloth.is_skirt:
        raise ctx.error("cloth.pin", "pin = \"waist\" needs shape = \"skirt\" or "
                                     "\"circle-skirt\"")
    if cloth.pin == "clamp" and cloth.shape != "disc":
        raise ctx.error("cloth.pin", "pin = \"clamp\" needs shape = \"disc\"")
    if cloth.shape == "disc" and cloth.pin not in ("clamp", "none"):
        raise ctx.error("cloth.pin", f"a disc is pinned at \"clamp\" or \"none\", got "
                                     f"{cloth.pin!r}")
    if cloth.is_skirt and cloth.pin not in ("waist", "none"):
        raise ctx.error("cloth.pin", f"a skirt is pinned at \"waist\" or \"none\", got "
                                     f"{cloth.pin!r}")
    for shape, pins in (("mesh", ("group", "vertices")), ("dress", ("shoulders",))):
        if (cloth.shape == shape) != (cloth.pin in pins) and cloth.pin != "none":
            allowed = ", ".join(f'"{pin}"' for pin in pins)
            raise ctx.error("cloth.pin", f"pin = {cloth.pin!r} does not apply to shape = "
                                         f"{cloth.shape!r}; a {shape} is pinned at {allowed} "
                                         f"or \"none\"")
    if cloth.pin == "group" and not cloth.pin_groups:
        raise ctx.error("cloth.pin_groups", "pin = \"group\" needs the groups, e.g. "
                                            "pin_groups = [\"waistband\"]")
    if cloth.pin == "vertices" and not cloth.pin_vertices:
        raise ctx.error("cloth.pin_vertices", "pin = \"vertices\" needs the vertex numbers, "
                                              "e.g. pin_vertices = [1, 2, 3]")
    if not cloth.springs:
        raise ctx.error("cloth.springs", "needs at least one spring family, e.g. [\"stretch\"]")
    scene = Scene(
        path=str(path),
        scene=info,
        simulation=build_table(ctx, SimulationConfig, raw.get("simulation", {}), "simulation"),
        cloth=cloth,
        effects=_build_effects(ctx, raw.get("effects", {}), cloth.bending),
        body=body,
        render=build_table(ctx, RenderConfig, raw.get("render", {}), "render"),
        output=build_table(ctx, OutputConfig, raw.get("output", {}), "output"),
        document=copy.deepcopy(raw),
    )
    for name in scene.effects:
        if EFFECT_BY_NAME[name].needs_body and scene.body is None:
            raise ctx.error(f"effects.{name}", f"{name} needs a [body] section")
    if scene.simulation.integrator == "implicit" and scene.simulation.arch in ("vulkan", "gpu"):
        raise ctx.error("simulation.arch", "the implicit integrator runs on the CPU and CUDA only: "
                                           "on Vulkan its conjugate gradients break down at random "
                                           "(a race not found yet); use arch = \"cpu\" or "
                                           "\"cuda\", or an explicit integrator")
    if "self_collision" in scene.effects and scene.simulation.arch != "cpu":
        raise ctx.error("simulation.arch", "self-collision runs on the CPU only: on CUDA its "
                                           "kernels were still compiling after 7 minutes (an "
                                           "H200), on Vulkan after 10; use arch = \"cpu\"")
    check_precision_range(ctx, scene)
    check_camera(ctx, scene.render)
    return scene


def check_camera(ctx: SourceContext, render: "RenderConfig") -> None:
    """The camera must look somewhere, and not straight along the up axis (y), where its
    left and right are undefined: either gave blank frames with exit 0."""
    view = np.subtract(render.camera_lookat, render.camera_position, dtype=float)
    length = float(np.linalg.norm(view))
    if not length > 1e-6:
        raise ctx.error("render.camera_position", "the camera sits on its look-at point; move "
                                                  "it away from render.camera_lookat")
    if np.hypot(view[0], view[2]) < 1e-3 * length:
        raise ctx.error("render.camera_position", "the camera looks straight along the up axis "
                                                  "(y); move it or the look-at point sideways")


F32_MAX, F32_TINY = float(np.finfo(np.float32).max), float(np.finfo(np.float32).tiny)


def check_precision_range(ctx: SourceContext, scene: Scene) -> None:
    """In float32 every number of the scene must be one float32 can hold: at most 3.4e38 in
    magnitude and, unless zero, at least its smallest normal 1.2e-38 (a larger one would become
    ±∞, a smaller one 0 or a subnormal that fast math flushes to 0: the cloth would silently
    lose gravity or stiffness). An InputError names the key."""
    if scene.simulation.precision != "f32":
        return
    for section in ("scene", "simulation", "cloth", "effects", "body", "render"):
        for dotted, value in numbers_in(getattr(scene, section), section):
            magnitude = abs(value)
            if magnitude > F32_MAX or 0 < magnitude < F32_TINY:
                raise ctx.error(dotted, f"{value:g} is outside float32's range (magnitudes "
                                        f"{F32_TINY:.3g} to {F32_MAX:.3g}); use "
                                        f"simulation.precision = \"f64\" or a value in range")


# the fabric values a [cloth.material] table can set (config.tables.MaterialOverrides)
MATERIAL_KEYS = ("density", "stretch_stiffness", "stretch_stiffness_weft", "shear_stiffness",
                 "bend_stiffness", "bend_stiffness_weft", "damping", "thickness")


def resolved_document(scene: Scene) -> dict:
    """The scene as a TOML document with every key spelled out (defaults, the preset's fabric
    values, the overrides applied): loading it gives the same ``Scene`` (``show``). Keys
    whose value is None (not set) are left out; tuples become lists."""
    def table(settings) -> dict:
        values = {}
        for field in dataclasses.fields(settings):
            value = getattr(settings, field.name)
            if dataclasses.is_dataclass(value):
                values[field.name] = table(value)  # a nested table (body.bvh)
            elif value is not None:
                values[field.name] = list(value) if isinstance(value, tuple) else value
        return values

    material = scene.material
    cloth = table(scene.cloth)
    cloth["material"] = {"preset": scene.cloth.material.preset,
                         **{key: getattr(material, key) for key in MATERIAL_KEYS
                            if getattr(material, key) is not None}}  # None: as the warp
    document = {"scene": table(scene.scene), "simulation": table(scene.simulation),
                "cloth": cloth,
                "effects": {name: table(settings) for name, settings in scene.effects.items()}}
    if scene.body is not None:
        document["body"] = table(scene.body)
    document.update(render=table(scene.render), output=table(scene.output))
    return document
