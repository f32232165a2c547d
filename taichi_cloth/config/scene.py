"""Scene files: TOML plus ``--set`` overrides into a frozen, validated ``Scene``.

Every key of every section is declared once, in the dataclasses below (and each effect's table in
its own ``Settings``, ``effects/``), with its default and its check (``settings.setting``).
``load_scene`` parses the file with ``tomllib``, applies the overrides, and
walks the tables against those declarations: an unknown key (with the closest valid one
suggested), a wrong type or an impossible value raises ``InputError`` naming the file (or the
``--set`` flag) and the dotted key. Units are SI, angles in degrees, y is up.
"""

import dataclasses
import difflib
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from taichi_cloth.config.materials import PRESETS, Material
from taichi_cloth.effects import EFFECT_BY_NAME
from taichi_cloth.errors import InputError
from taichi_cloth.runtime import ARCH_NAMES
from taichi_cloth.settings import SourceContext, build_table, numbers_in, setting

# The shipped scenes: the repository's top-level scenes/ (taichi_cloth/scenes links to it, and an
# installed package carries the files there: pyproject.toml)
SCENES_DIR = (Path(__file__).parents[1] / "scenes").resolve()
INTEGRATOR_NAMES = ("euler", "symplectic", "rk4", "implicit")
SPRING_FAMILIES = ("stretch", "shear")  # "bend" springs come with cloth.bending = "springs"
BENDING_MODELS = ("curvature", "springs", "none")
MESH_FORMATS = ("obj", "ply", "vtu", "xdmf", "usd", "pc2")


@dataclass(frozen=True)
class SceneInfo:
    name: str = setting("", "str", doc="scene name; defaults to the file's stem")
    description: str = setting("", "str")
    duration: float = setting(4.0, "float", low=0.0, high=1e6, low_inclusive=False,
                              doc="seconds (at most 1e6: eleven days of animation)")
    fps: int = setting(30, "int", low=1, high=1000, doc="frames per second")


@dataclass(frozen=True)
class SimulationConfig:
    integrator: str = setting("symplectic", "str", choices=INTEGRATOR_NAMES)
    dt: Any = setting("auto", "dt", low=0.0, low_inclusive=False,
                      doc="time step [s], or \"auto\" to derive it from the stability bound")
    arch: str = setting("cpu", "str", choices=ARCH_NAMES)
    precision: str = setting("f32", "str", choices=("f32", "f64"))
    safety: float = setting(0.8, "float", low=0.0, high=1.0, low_inclusive=False,
                            doc="fraction of the stability bound used by dt = \"auto\"")
    blowup_strain: float = setting(1.0, "float", low=0.0, low_inclusive=False,
                                   doc="max stretch-spring strain at which a frame counts as exploded")
    max_speed: float = setting(50.0, "float", low=0.0, low_inclusive=False,
                               doc="particle speed [m/s] at which a frame counts as exploded")
    max_retries: int = setting(4, "int", low=0, high=20,
                               doc="times a bad frame is redone with the step halved")
    settle: float = setting(0.0, "float", low=0.0, high=60.0,
                            doc="seconds at most that the garment settles on the body, held "
                                "still, before frame 0 (0: start from the pattern shape)")
    settle_speed: float = setting(0.005, "float", low=0.0, low_inclusive=False,
                                  doc="mean particle speed [m/s] at which settling stops")
    cg_tolerance: float = setting(1e-3, "float", low=0.0, low_inclusive=False,
                                  doc="implicit integrator: relative residual of conjugate gradients")
    cg_max_iterations: int = setting(500, "int", low=1, high=100000)
    newton_iterations: int = setting(1, "int", low=1, high=50,
                                     doc="implicit integrator: linearisations per step (1 = "
                                         "Baraff & Witkin)")


@dataclass(frozen=True)
class MaterialOverrides:
    preset: str = setting("cotton", "str", choices=tuple(PRESETS))
    density: float | None = setting(None, "float", low=0.0, low_inclusive=False, doc="kg/m²")
    stretch_stiffness: float | None = setting(None, "float", low=0.0, low_inclusive=False, doc="N/m")
    shear_stiffness: float | None = setting(None, "float", low=0.0, doc="N/m")
    bend_stiffness: float | None = setting(None, "float", low=0.0, doc="N·m, warp")
    bend_stiffness_weft: float | None = setting(None, "float", low=0.0, doc="N·m")
    stretch_stiffness_weft: float | None = setting(None, "float", low=0.0, low_inclusive=False,
                                                   doc="N/m")
    damping: float | None = setting(None, "float", low=0.0, doc="Rayleigh damping time β [s]")
    thickness: float | None = setting(None, "float", low=0.0, low_inclusive=False, doc="m")

    def resolve(self) -> Material:
        """The preset with the given values replaced. A warp value given without its weft value
        (stretch_stiffness, bend_stiffness) sets both directions: the fabric becomes isotropic
        in it."""
        changed = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                   if f.name != "preset" and getattr(self, f.name) is not None}
        for warp in ("stretch_stiffness", "bend_stiffness"):
            if warp in changed:
                changed.setdefault(f"{warp}_weft", None)
        return dataclasses.replace(PRESETS[self.preset], **changed)


@dataclass(frozen=True)
class ClothConfig:
    shape: str = setting("sheet", "str", choices=("skirt", "circle-skirt", "sheet", "disc"),
                         doc="skirt: a cone from waist_radius to hem_radius; circle-skirt: "
                             "cut from a fraction `circle` of an annulus; disc: a flat "
                             "circular specimen (Cusick drape), rings from waist_radius to "
                             "hem_radius at height")
    resolution: tuple = setting([24, 24], "int_list", low=2, high=4096, length=2,
                                doc="[around, down] for a skirt, [x, z] for a sheet")
    material: MaterialOverrides = setting(MaterialOverrides(), "table", shorthand="preset",
                                          doc="a preset name, or a table of overrides")
    pin: str = setting("top-edge", "str",
                       choices=("waist", "top-edge", "corners", "clamp", "none"),
                       doc="clamp: a disc's particles within clamp_radius of its centre")
    pin_rows: int = setting(1, "int", low=1, high=4096,
                            doc="top-edge: rows held (2 clamp the edge's slope too)")
    clamp_radius: float = setting(0.09, "float", low=0.0, doc="disc, pin = \"clamp\": m")
    springs: tuple = setting(list(SPRING_FAMILIES), "str_list", choices=SPRING_FAMILIES,
                             doc="in-plane spring families")
    bending: str = setting("curvature", "str", choices=BENDING_MODELS,
                           doc="curvature: the bending effect from the fabric's B (effects/"
                               "bending.py); springs: the seed's skip-one springs; none")
    bias: float = setting(0.0, "float", low=-90.0, high=90.0,
                          doc="degrees the warp is turned from the garment's length (45: bias cut)")
    circle: float = setting(1.0, "float", low=0.0, low_inclusive=False, high=1.0,
                            doc="circle-skirt: the fraction of a full circle its pattern spans "
                                "(1 full, 0.5 half); hem radius = waist_radius + circle·length")
    waist_radius: float = setting(0.17, "float", low=0.0, low_inclusive=False, doc="skirt, m")
    hem_radius: float = setting(0.40, "float", low=0.0, low_inclusive=False, doc="skirt, m")
    length: float = setting(0.55, "float", low=0.0, low_inclusive=False, doc="skirt, m")
    waist_height: float = setting(1.0, "float", doc="skirt without a body: height of the waist, m")
    size: tuple = setting([1.0, 1.0], "float_list", low=0.0, low_inclusive=False, length=2,
                          doc="sheet [x, z] extent, m")
    height: float = setting(1.0, "float", doc="sheet: y of its top edge (vertical) or plane, m")
    orientation: str = setting("vertical", "str", choices=("vertical", "horizontal"),
                               doc="sheet hangs in the x-y plane or lies in the x-z plane")
    ripple: tuple = setting([0.0, 1.0], "float_list", low=0.0, length=2,
                            doc="sheet: [amplitude m, half-waves] of a wave across its plane, "
                                "down its length, in the start shape (the rest shape stays "
                                "flat): lets a sheet dropped on its edge buckle")

    @property
    def is_skirt(self) -> bool:
        """A wrap-around skirt, worn at the waist (``skirt`` or ``circle-skirt``)."""
        return self.shape in ("skirt", "circle-skirt")

    @property
    def skirt_flare(self) -> float:
        """How much wider [m] a skirt's hem circle is than its waist: hem_radius −
        waist_radius, or for a circle skirt circle·length (a pattern spanning the fraction
        ``circle`` of an annulus of inner radius waist_radius/circle, sewn into a cone; a full
        circle lies flat)."""
        if self.shape == "circle-skirt":
            return self.circle * self.length
        return self.hem_radius - self.waist_radius


@dataclass(frozen=True)
class BodyConfig:
    motion: str = setting("still", "str", choices=("hula", "sway", "twirl", "still"),
                          doc="sway: rocks side to side, feet planted; twirl: spins and stops")
    tempo: float = setting(90.0, "float", low=0.0, low_inclusive=False, high=400.0,
                           doc="beats per minute")
    amplitude: float = setting(1.0, "float", low=0.0, high=3.0, doc="scale of sway and circles; twirl: turns")
    capsules: str = setting("split", "str", choices=("split", "coarse", "bar", "ball"),
                            doc="paper Fig. 4, Fig. 3, or one static bar or ball (draping)")
    scale: float = setting(1.0, "float", low=0.1, high=10.0, doc="body size relative to 1.6 m")
    ease_in: float = setting(1.0, "float", low=0.0, doc="seconds from rest to full motion")


@dataclass(frozen=True)
class RenderConfig:
    width: int = setting(640, "int", low=16, high=8192, doc="frame width, pixels")
    height: int = setting(480, "int", low=16, high=8192, doc="frame height, pixels")
    camera_position: tuple = setting([0.9, 1.25, 3.1], "float_list", length=3, doc="m")
    camera_lookat: tuple = setting([0.0, 0.8, 0.0], "float_list", length=3, doc="m")
    fov: float = setting(40.0, "float", low=1.0, high=170.0, doc="vertical field of view, degrees")
    texture: str = setting("", "str", doc="cloth print: an image file relative to the scene "
                                          "file; \"\" = the shipped pareo print on a skirt and "
                                          "cloth_color on a sheet; \"none\" = cloth_color")
    texture_repeat: tuple = setting([1.0, 1.0], "float_list", low=0.0, low_inclusive=False,
                                    length=2, doc="times the image tiles across [u, v]")
    cloth_color: tuple = setting([0.85, 0.3, 0.25], "float_list", low=0.0, high=1.0, length=3)
    subdivision: int = setting(6, "int", low=1, high=16,
                               doc="render vertices per cloth particle spacing (smooth "
                                   "Catmull-Rom surface through the particles)")
    body_color: tuple = setting([0.80, 0.58, 0.45], "float_list", low=0.0, high=1.0, length=3,
                                doc="skin")
    background: tuple = setting([0.80, 0.87, 0.93], "float_list", low=0.0, high=1.0, length=3)
    ground: bool = setting(True, "bool", doc="draw a floor at y = 0 (or [effects.ground] height)")
    ambient: float = setting(0.38, "float", low=0.0, high=2.0,
                             doc="light from everywhere, fraction of a surface's colour")
    light: float = setting(0.62, "float", low=0.0, high=2.0,
                           doc="key light above the camera's right shoulder (a fill light from "
                               "the left has a third of it)")


@dataclass(frozen=True)
class OutputConfig:
    dir: str = setting("", "str", doc="output folder; default output/<scene>")
    meshes: tuple = setting([], "str_list", choices=MESH_FORMATS,
                            doc="cloth meshes per frame (xdmf: one time series; usd: one "
                                "stage with the body; pc2: a point cache beside an OBJ)")
    video: str = setting("", "str", choices=("", "mp4", "gif"), doc="render: also a video")
    body_meshes: bool = setting(False, "bool", doc="also export the body capsules as meshes")


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


def load_scene(name_or_path: str, overrides: tuple[str, ...] = ()) -> Scene:
    """Read, override and validate a scene. Raises ``InputError`` on any bad input."""
    path = resolve_scene_path(name_or_path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"{path}: not valid TOML: {error}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read: {error}") from None
    overridden = []
    for text in overrides:
        parts, value = parse_override(text)
        apply_override(raw, parts, value)
        overridden.append(".".join(parts))
    ctx = SourceContext(str(path), overridden)
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
    )
    for name in scene.effects:
        if EFFECT_BY_NAME[name].needs_body and scene.body is None:
            raise ctx.error(f"effects.{name}", f"{name} needs a [body] section")
    if scene.simulation.integrator == "implicit" and scene.simulation.arch != "cpu":
        raise ctx.error("simulation.arch", "the implicit integrator runs on the CPU only: on "
                                           "Vulkan its conjugate gradients break down at random "
                                           "(a race not found yet); use arch = \"cpu\" or an "
                                           "explicit integrator")
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
