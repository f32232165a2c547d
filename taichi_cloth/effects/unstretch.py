"""The springs that self-collision's put-backs stretched, shortened again (docs/physics.md, "Two
bounds on putting pairs back"): Provot (1995, "Deformation constraints in a mass-spring model to
describe rigid cloth behavior")'s deformation constraint, applied to those springs only."""

import taichi as ti

STRAIN_ALLOWANCE = 0.01  # a spring the sweeps stretch is shortened to this strain (or its own)


@ti.func
def unstretch(model, state, unswept_x, lifted):
    """Each stretch spring at a particle that a sweep has moved (``lifted``), longer than both
    its length before the sweeps (``unswept_x``) and (1 + ``STRAIN_ALLOWANCE``) times its rest
    length, shortened to the longer of the two: its ends moved along it by their shares of
    inverse mass. Putting a pair back moves its particles by up to the thickness, a third of a
    1.1 cm edge at a skirt's waist: unbounded, these moves stretched the fastest spins' waists to
    4.7–5 % at 150–180 bpm."""
    inverse_mass = ti.static(model.particle_inv_mass)
    allowance = model.real(1.0 + STRAIN_ALLOWANCE)
    for i in range(model.particle_count):
        if lifted[i]:
            for k in range(model.particle_spring_start[i], model.particle_spring_start[i + 1]):
                spring = model.particle_spring[k]
                j = model.particle_neighbor[k]
                weight = inverse_mass[i] + inverse_mass[j]
                if spring < ti.static(model.stretch_count) and weight > 0:
                    d = state.x[j] - state.x[i]
                    length = d.norm()
                    allowed = ti.max((unswept_x[j] - unswept_x[i]).norm(),
                                     allowance * model.spring_rest_length[spring])
                    if length > allowed:
                        shift = (length - allowed) / (length * weight) * d
                        state.x[i] += inverse_mass[i] * shift
                        state.x[j] -= inverse_mass[j] * shift
