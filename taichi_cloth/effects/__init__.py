"""Effects a scene may declare under ``[effects]``, one file each (``base.py`` says what an
effect declares). ``EFFECTS`` is the one place they are registered: its order is the order in
which forces are summed and effects are listed in ``stats.json``."""

import taichi as ti

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


@ti.data_oriented
class PostSteps:
    """Several effects' post steps as one (``Integrator``'s ``post_step``), applied in the
    effects' order: a contact projection before self-collision's side records."""

    def __init__(self, post_steps: list):
        self.post_steps = tuple(post_steps)

    @ti.func
    def apply(self, state, t):
        for k in ti.static(range(len(self.post_steps))):
            self.post_steps[k].apply(state, t)


def post_step_of(effects: list[Effect]):
    """The effects' post steps as one object for the integrator, or None when none has one."""
    post_steps = [effect.post_step for effect in effects if effect.post_step is not None]
    return PostSteps(post_steps) if post_steps else None
