"""Fabric presets from KES-style measurements, and their mapping to per-spring constants.

The seed paper (§2.2) models cloth by four of the Kawabata Evaluation System (KES) properties:
tensile, shear, bending and weight. KES measures tensile extension and bending per direction,
warp (-1) and weft (-2). A preset stores those measurements in KES units, as the literature
tabulates them, and converts them to SI continuum constants:

- weight W [mg/cm²]                → areal density ρ = W · 0.01            [kg/m²]
- tensile extension EMT [%] at the KES load of 500 gf/cm = 490.3 N/m
                                    → membrane stiffness k_m = 490.3 / (EMT/100)   [N/m]
- shear rigidity G [gf/(cm·deg)]   → shear modulus G_si = G · 0.00980665/0.01 · 180/π  [N/m]
- bending rigidity B [gf·cm²/cm]   → B_si = B · 0.00980665·1e-4 / 0.01 = B · 9.80665e-5 [N·m]

Typical values: Kawabata & Niwa, "Fabric performance in clothing and clothing manufacture"
(J. Text. Inst. 80, 1989) and Inoue, Sen'i Gakkaishi 64(8), 2008 (the seed's ref. 5); each preset
is a representative mid-range fabric of its kind, not one measured sample.

Mapping to springs (``spring_constants``), for a grid with spacing dx (along a row) and dz (down
a column), so that refining the grid keeps the cloth's behaviour:

- stretch spring along x, length dx, stands for a strip of width dz:  k = k_m · dz / dx.
  On a square grid k = k_m whatever the spacing; the particle mass ρ·dx·dz shrinks with the cell,
  so the wave speed √(k_m/ρ) is resolution independent.
- shear: the two diagonals of a dx × dz cell, each with k = G_si·(dx² + dz²)/(2·dx·dz), give the
  cell the small-strain shear modulus G_si (energy ½·G·γ² per unit area); k = G_si on a square.
- stretch per direction: a spring at angle φ to the warp takes k_m(φ) = k_warp·cos²φ + k_weft·sin²φ
  (on a garment cut with a bias angle b, a row spring lies at φ = b, a column spring at 90° − b).
- bend (``cloth.bending = "springs"``, the seed's model): skip-one springs of length 2h,
  k = B_warp / (dx·dz). This is a stand-in for B, not a discretisation of it: a straight skip-one
  spring changes length only to second order in the curvature κ, so its energy goes as κ⁴·h² and
  fades as the grid is refined (a sheet bent to a fixed κ stores 1/4 of the energy at half the
  spacing). The default, ``cloth.bending = "curvature"``, is the curvature bending effect
  (``effects/bending.py``), a discretisation of B_warp and B_weft that does not fade.
- dashpots: stiffness-proportional (Rayleigh) damping, c = β · k [N·s/m] per spring, β [s] from the
  preset. A mode of angular frequency ω is damped with ratio ζ = β·ω/2, the same for every
  resolution.
"""

from dataclasses import dataclass

KES_LOAD_N_PER_M = 490.3325  # 500 gf/cm in N/m
GRAM_FORCE_N = 9.80665e-3
STANDARD_GRAVITY = 9.81  # m/s², the bending length's g (as the scenes' default gravity)


@dataclass(frozen=True)
class Material:
    """A fabric in SI units.

    density: areal density [kg/m²]; stretch_stiffness: membrane stiffness k_m along the warp
    [N/m]; shear_stiffness: in-plane shear modulus [N/m]; bend_stiffness: bending rigidity B of
    the warp [N·m] (a strip cut along the warp bends with it); damping: stiffness-proportional
    damping time β [s]; thickness: cloth thickness [m]; stretch_stiffness_weft,
    bend_stiffness_weft: the same along the weft (None: as the warp).
    """

    name: str
    density: float
    stretch_stiffness: float
    shear_stiffness: float
    bend_stiffness: float
    damping: float
    thickness: float
    description: str = ""
    stretch_stiffness_weft: float | None = None
    bend_stiffness_weft: float | None = None

    @property
    def stretch_weft(self) -> float:
        """k_m along the weft [N/m]."""
        return self.stretch_stiffness if self.stretch_stiffness_weft is None \
            else self.stretch_stiffness_weft

    @property
    def bend_weft(self) -> float:
        """B along the weft [N·m]."""
        return self.bend_stiffness if self.bend_stiffness_weft is None \
            else self.bend_stiffness_weft

    @property
    def bending_length(self) -> tuple[float, float]:
        """c = (B/(ρ_A·g))^(1/3) [m] of the warp and the weft (g = 9.81 m/s²): the length the
        cantilever test measures (Peirce 1930)."""
        return tuple((rigidity / (self.density * STANDARD_GRAVITY)) ** (1.0 / 3.0)
                     for rigidity in (self.bend_stiffness, self.bend_weft))


@dataclass(frozen=True)
class KesMeasurement:
    """KES-FB values as published: W [mg/cm²], EMT [%], G [gf/(cm·deg)], B [gf·cm²/cm], T [mm];
    extension and bending_rigidity of the warp, ``*_weft`` of the weft."""

    weight: float
    extension: float
    shear_rigidity: float
    bending_rigidity: float
    thickness: float
    extension_weft: float
    bending_rigidity_weft: float


def material_from_kes(name: str, kes: KesMeasurement, damping: float, description: str) -> Material:
    """Convert KES units to SI (the formulas in this module's docstring)."""
    degrees_per_radian = 180.0 / 3.141592653589793
    return Material(
        name=name,
        density=kes.weight * 0.01,
        stretch_stiffness=KES_LOAD_N_PER_M / (kes.extension / 100.0),
        stretch_stiffness_weft=KES_LOAD_N_PER_M / (kes.extension_weft / 100.0),
        shear_stiffness=kes.shear_rigidity * GRAM_FORCE_N / 0.01 * degrees_per_radian,
        bend_stiffness=kes.bending_rigidity * GRAM_FORCE_N * 1e-4 / 0.01,
        bend_stiffness_weft=kes.bending_rigidity_weft * GRAM_FORCE_N * 1e-4 / 0.01,
        damping=damping,
        thickness=kes.thickness * 1e-3,
        description=description,
    )


PRESETS: dict[str, Material] = {
    m.name: m
    for m in (
        material_from_kes("cotton", KesMeasurement(13.0, 4.0, 0.9, 0.08, 0.40, 6.0, 0.06), 2e-5,
                          "plain-weave cotton shirting, ~130 g/m²"),
        material_from_kes("silk", KesMeasurement(6.0, 6.0, 0.4, 0.02, 0.20, 9.0, 0.015), 2e-5,
                          "silk habutai, light and supple, ~60 g/m²"),
        material_from_kes("denim", KesMeasurement(40.0, 3.0, 3.0, 0.80, 0.90, 6.0, 0.50), 3e-5,
                          "12 oz cotton denim twill, heavy and stiff, ~400 g/m²"),
        material_from_kes("wool", KesMeasurement(22.0, 8.0, 0.6, 0.10, 0.60, 10.0, 0.08), 3e-5,
                          "worsted wool suiting, ~220 g/m²"),
        material_from_kes("polyester", KesMeasurement(10.0, 3.0, 0.7, 0.05, 0.25, 4.0, 0.04),
                          1.5e-5, "plain-weave polyester, ~100 g/m²"),
    )
}


@dataclass(frozen=True)
class SpringConstants:
    """Per-spring stiffness [N/m] of each family."""

    stretch_x: float
    stretch_z: float
    shear: float
    bend: float


def stretch_modulus(material: Material, cos_sq):
    """k_m(φ) = k_warp·cos²φ + k_weft·sin²φ [N/m] along a direction at angle φ to the warp."""
    return material.stretch_stiffness * cos_sq + material.stretch_weft * (1.0 - cos_sq)


def spring_constants(material: Material, spacing_x, spacing_z, row_cos_sq=0.0,
                     column_cos_sq=1.0) -> SpringConstants:
    """Per-spring constants for a grid with spacings dx (along a row) and dz (down a column)
    [m]; row_cos_sq, column_cos_sq: cos² of the angle between a row (column) spring and the warp
    (by default the warp runs down the columns). Module docstring for the why."""
    return SpringConstants(
        stretch_x=stretch_modulus(material, row_cos_sq) * spacing_z / spacing_x,
        stretch_z=stretch_modulus(material, column_cos_sq) * spacing_x / spacing_z,
        shear=material.shear_stiffness * (spacing_x ** 2 + spacing_z ** 2)
        / (2 * spacing_x * spacing_z),
        bend=material.bend_stiffness / (spacing_x * spacing_z),
    )
