"""The scene file's tables: one frozen dataclass per section (``[scene]``, ``[simulation]``,
``[cloth]`` with its ``[cloth.material]``, ``[body]``, ``[render]``, ``[output]``), each key
declared once with its default, kind, bounds and unit (``settings.setting``). An effect's table
is declared in its own file (``effects/``); ``config.scene`` reads a file into them.
"""

import dataclasses
from dataclasses import dataclass
from typing import Any

from taichi_cloth.config.materials import PRESETS, Material
from taichi_cloth.runtime import ARCH_NAMES
from taichi_cloth.settings import setting

INTEGRATOR_NAMES = ("euler", "symplectic", "rk4", "implicit")
SPRING_FAMILIES = ("stretch", "shear")  # "bend" springs come with cloth.bending = "springs"
BENDING_MODELS = ("curvature", "springs", "none")
MESH_FORMATS = ("obj", "ply", "vtu", "xdmf", "usd", "pc2")
DENSITY_RANGE = (1e-3, 20.0)  # kg/m², the areal densities a cloth may have


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
    redo_strain: float = setting(0.0, "float", low=0.0,
                                 doc="a frame that ends with a larger max strain is redone at "
                                     "half, a quarter, then an eighth of the step (past 10 %, "
                                     "or after tunnelling, down to a 64th; not where the "
                                     "garment holds it: a tight waist), its best try kept "
                                     "(0: never)")
    redo_penetration: float = setting(0.0, "float", low=0.0,
                                      doc="a frame that ends with a point of the cloth's surface "
                                          "deeper than this [m] inside a collider (capsule, "
                                          "ground, plate; without the margin) is redone at half, "
                                          "a quarter, then an eighth of the step (after "
                                          "tunnelling, down to a 64th; not where the garment "
                                          "holds it), its best try kept (0: never)")
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
    # tissue paper is ~0.015 kg/m², chain mail ~10; 130 would be cotton's 130 g/m² typed as kg/m²
    density: float | None = setting(None, "float", low=DENSITY_RANGE[0], high=DENSITY_RANGE[1],
                                    doc="kg/m²; a fabric's g/m² over 1000")
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
    shape: str = setting("sheet", "str",
                         choices=("skirt", "circle-skirt", "pleated", "dress", "sheet", "disc",
                                  "mesh"),
                         doc="skirt: a cone (A-line) from waist_radius to hem_radius; "
                             "circle-skirt: cut from a fraction `circle` of an annulus; "
                             "pleated: the cone with `pleats` box or knife pleats `pleat_depth` "
                             "deep; "
                             "disc: a flat circular specimen (Cusick drape), rings from "
                             "waist_radius to hem_radius at height; dress: a bodice, the "
                             "skirt's cone and two shoulder straps (cloth/dress.py); mesh: the "
                             "triangles "
                             "and quads of the OBJ file `mesh`")
    bodice_radius: float = setting(0.135, "float", low=0.0, low_inclusive=False,
                                   doc="dress: m, the bodice's tube round the torso")
    bodice_height: float = setting(0.26, "float", low=0.0, low_inclusive=False,
                                   doc="dress: m from the waist up to the bodice's top edge")
    strap_width: float = setting(0.035, "float", low=0.0, low_inclusive=False,
                                 doc="dress: m, each shoulder strap")
    mesh: str = setting("", "str", doc="mesh: an OBJ file, relative to the scene file; its "
                                       "coordinates y up, in units of mesh_scale")
    mesh_scale: float = setting(1.0, "float", low=0.0, low_inclusive=False,
                                doc="mesh: metres per file unit (0.01 for centimetres)")
    mesh_offset: tuple = setting([0.0, 0.0, 0.0], "float_list", length=3,
                                 doc="mesh: m added to every vertex after scaling")
    pleats: int = setting(12, "int", low=2, high=512, doc="pleated: pleats around")
    pleat_depth: float = setting(0.02, "float", low=0.0, low_inclusive=False,
                                 doc="pleated: m from a pleat's inner to its outer fold")
    pleat_style: str = setting("box", "str", choices=("box", "knife"),
                               doc="pleated: box (folds alternating in and out, particles around "
                                   "a multiple of 2 × pleats) or knife (all facing one way, a "
                                   "multiple of pleats, at least 3 a pleat)")
    resolution: tuple = setting([24, 24], "int_list", low=2, high=4096, length=2,
                                doc="[around, down] for a skirt, [x, z] for a sheet")
    material: MaterialOverrides = setting(MaterialOverrides(), "table", shorthand="preset",
                                          doc="a preset name, or a table of overrides")
    pin: str = setting("top-edge", "str",
                       choices=("waist", "top-edge", "left-edge", "corners", "clamp", "group",
                                "vertices", "shoulders", "none"),
                       doc="left-edge: a sheet's first column (a flag's hoist); clamp: a "
                           "disc's particles within clamp_radius of its centre; group, "
                           "vertices: a mesh's pin_groups or pin_vertices; shoulders: a "
                           "dress's straps (carried by the dancer's pelvis, or chest above "
                           "the middle of her back, when there is one)")
    pin_groups: tuple = setting([], "str_list", doc="mesh, pin = \"group\": OBJ group (g) or "
                                                    "object (o) names whose vertices are held")
    pin_vertices: tuple = setting([], "int_list", low=1,
                                  doc="mesh, pin = \"vertices\": vertex numbers as in the OBJ "
                                      "file (from 1)")
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
        """A wrap-around skirt, worn at the waist (``skirt``, ``circle-skirt``, ``pleated``)."""
        return self.shape in ("skirt", "circle-skirt", "pleated")

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
class BvhConfig:
    """[body.bvh] (or body.bvh = "clip.bvh"): the motion capture clip of body.motion = "bvh"
    (``body/mocap.py``)."""

    file: str = setting("", "str", doc="a .bvh file, relative to the scene file")
    units: str = setting("auto", "str", choices=("auto", "m", "cm", "inch"),
                         doc="the file's length unit (auto: from the leg's length)")
    up: str = setting("auto", "str", choices=("auto", "y", "z"),
                      doc="the file's up axis (auto: along hips to neck)")
    start: float = setting(0.0, "float", low=0.0, doc="s into the clip where the dance starts")
    end: float = setting(0.0, "float", low=0.0, doc="s into the clip where it ends; 0 = the end")
    loop: str = setting("auto", "str", choices=("auto", "yes", "no"),
                        doc="auto: when the last frame repeats the first; no: hold the last")
    joints: tuple = setting([], "str_list", doc="\"ours=theirs\" joint names beyond the "
                                                "built-in Mixamo and CMU maps")


@dataclass(frozen=True)
class BodyConfig:
    motion: str = setting("still", "str",
                          choices=("hula", "sway", "twirl", "walk", "bvh", "still"),
                          doc="sway: rocks side to side, feet planted; twirl: spins and stops; "
                              "walk: on the spot; bvh: the motion capture clip [body.bvh]")
    bvh: BvhConfig = setting(BvhConfig(), "table", shorthand="file",
                             doc="motion = \"bvh\": the clip and how to read it")
    tempo: float = setting(90.0, "float", low=0.0, low_inclusive=False, high=400.0,
                           doc="beats per minute")
    amplitude: float = setting(1.0, "float", low=0.0, high=3.0, doc="scale of sway and circles; twirl: turns")
    capsules: str = setting("split", "str", choices=("split", "coarse", "bar", "ball", "pole"),
                            doc="paper Fig. 4, Fig. 3, or one static bar or ball (draping) or "
                                "a flagpole")
    offset: tuple = setting([0.0, 0.0, 0.0], "float_list", length=3,
                            doc="bar, ball, pole: where the prop stands, moved from its place, m")
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
