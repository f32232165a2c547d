"""Effects a scene may declare under ``[effects]``, one file each (``base.py`` says what an
effect declares). ``EFFECTS`` is the one place they are registered: its order is the order in
which forces are summed and effects are listed in ``stats.json``."""

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.bending import Bending
from taichi_cloth.effects.collision import CapsuleContact
from taichi_cloth.effects.damping import Damping
from taichi_cloth.effects.drag import Drag
from taichi_cloth.effects.gravity import Gravity
from taichi_cloth.effects.ground import GroundContact
from taichi_cloth.effects.self_collision import SelfCollision
from taichi_cloth.effects.support import SupportContact
from taichi_cloth.effects.wind import Wind

EFFECTS = (Gravity, Damping, Bending, Drag, Wind, CapsuleContact, GroundContact, SupportContact,
           SelfCollision)
EFFECT_BY_NAME = {effect.name: effect for effect in EFFECTS}


def model_options(declared: dict) -> dict:
    """What the declared effects ask of the model (``Effect.model_options``), merged."""
    options = {}
    for name, settings in declared.items():
        options.update(EFFECT_BY_NAME[name].model_options(settings))
    return options


def build_effects(declared: dict, context: EffectContext) -> list[Effect]:
    """The effect objects of ``declared`` (``Scene.effects``: name → settings, in ``EFFECTS``
    order)."""
    return [EFFECT_BY_NAME[name](settings, context) for name, settings in declared.items()]
