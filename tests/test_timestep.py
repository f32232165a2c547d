"""The time step: a requested dt rounded to whole substeps per frame, the highest frequency of the
cloth against the exact eigenvalues of M⁻¹K, and ``dt = "auto"`` against the closed-form
stability limits of the integrators on one spring."""

import math

import numpy as np
import pytest

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.scene import load_scene
from taichi_cloth.effects.penalty import ContactMode
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.physics import simulation as simulation_module
from taichi_cloth.physics.integrators.stability import contact_step_limit
from taichi_cloth.physics.simulation import Simulation
from taichi_cloth.physics.timestep import (IMPLICIT_PIN_TRAVEL, choose_time_step, fixed_time_step,
                                          highest_frequency)

FRAME = 1.0 / 30.0


@pytest.mark.parametrize("requested, substeps", [
    (0.002, 17),         # 16.67 steps per frame round up to 17
    (1.0 / 60.0, 2),     # an exact divisor is kept
    (1.0 / 300.0, 10),   # another one, despite 1/30 ÷ 1/300 rounding to 10.000000000000002
    (0.1, 1),            # longer than the frame: the frame itself
])
def test_fixed_step_splits_the_frame_into_the_fewest_equal_substeps(requested, substeps):
    step = fixed_time_step(requested, FRAME)
    assert step.substeps_per_frame == substeps
    assert step.dt == pytest.approx(FRAME / substeps, rel=1e-15)
    assert step.dt <= requested * (1 + 1e-12)
    if substeps > 1:
        assert FRAME / (substeps - 1) > requested  # one substep fewer would be too long


def test_fixed_step_of_seventeen_substeps_is_one_five_hundred_and_tenth():
    assert fixed_time_step(0.002, FRAME).dt == pytest.approx(1.0 / 510.0, rel=1e-15)


def test_random_requests_never_exceed_the_request_and_use_the_fewest_substeps():
    rng = np.random.default_rng(11)
    for requested in 10.0 ** rng.uniform(-5, -1, 200):
        step = fixed_time_step(requested, FRAME)
        assert step.dt * step.substeps_per_frame == pytest.approx(FRAME, rel=1e-14)
        assert step.dt <= requested * (1 + 1e-9)
        assert step.substeps_per_frame == 1 or FRAME / (step.substeps_per_frame - 1) > requested


def stiffness_matrix(positions, ends, stiffness):
    """K (3N × 3N) of springs at rest: blocks k·n·nᵀ on the diagonal, −k·n·nᵀ off it."""
    count = len(positions)
    matrix = np.zeros((3 * count, 3 * count))
    for (i, j), k in zip(ends, stiffness):
        direction = positions[j] - positions[i]
        direction /= np.linalg.norm(direction)
        block = k * np.outer(direction, direction)
        for a, b, sign in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
            matrix[3 * a:3 * a + 3, 3 * b:3 * b + 3] += sign * block
    return matrix


def exact_largest_eigenvalue(positions, ends, stiffness, mass, free):
    """λ_max of M⁻¹K on the free particles, from the symmetric M^-½·K·M^-½."""
    dofs = np.repeat(free, 3)
    scale = 1.0 / np.sqrt(np.repeat(mass, 3))[dofs]
    reduced = stiffness_matrix(positions, ends, stiffness)[np.ix_(dofs, dofs)]
    return float(np.linalg.eigvalsh(scale[:, None] * reduced * scale[None, :]).max())


def gershgorin_bound(ends, stiffness, mass, free):
    """max over free particles of 2·Σ_{springs at i} k / m_i."""
    bound = 0.0
    for i in np.flatnonzero(free):
        touching = (ends[:, 0] == i) | (ends[:, 1] == i)
        bound = max(bound, 2.0 * stiffness[touching].sum() / mass[i])
    return bound


def free_chain():
    """Eight particles on a jittered line, every one free, uneven springs and masses."""
    rng = np.random.default_rng(5)
    count = 8
    positions = np.stack([0.1 * np.arange(count), np.zeros(count), np.zeros(count)], axis=1)
    positions += 0.02 * rng.standard_normal(positions.shape)
    ends = np.stack([np.arange(count - 1), np.arange(1, count)], axis=1)
    return (positions, ends, rng.uniform(50.0, 200.0, count - 1),
            rng.uniform(0.01, 0.05, count), np.ones(count, dtype=bool))


def pinned_grid():
    """A 4 × 4 cotton sheet with all three spring families, hanging from its two top corners."""
    scene = load_scene("sheet", ("cloth.resolution=[4, 4]",))
    garment = build_garment(scene.cloth, scene.material)
    ends = np.concatenate([garment.springs[f] for f in garment.springs])
    stiffness = np.concatenate([garment.spring_stiffness[f] for f in garment.springs])
    return garment.positions, ends, stiffness, garment.mass, ~garment.pinned


@pytest.mark.parametrize("system", [free_chain, pinned_grid])
def test_highest_frequency_brackets_the_exact_eigenvalue(system):
    """λ ≤ ω² ≤ min(1.1·λ, Gershgorin): never below the truth (a step from it is stable), and
    at most the 10 % headroom above it. With uneven masses u·M⁻¹Ku/|u|² is no Rayleigh
    quotient and may overshoot λ slightly before it converges: 1e-6 of slack above 1.1·λ."""
    positions, ends, stiffness, mass, free = system()
    exact = exact_largest_eigenvalue(positions, ends, stiffness, mass, free)
    omega = highest_frequency(positions.copy(), ends, stiffness, mass, free)
    bound = gershgorin_bound(ends, stiffness, mass, free)
    assert exact <= bound * (1 + 1e-12)  # the oracle's own bound holds
    assert omega ** 2 >= 0.999 * exact
    assert omega ** 2 <= 1.1 * exact * (1 + 1e-6)
    assert omega ** 2 <= bound * (1 + 1e-12)


def test_highest_frequency_ignores_pinned_particles():
    """A light particle that is pinned sets no frequency: only the free ones count."""
    positions, ends, stiffness, mass, free = free_chain()
    mass = mass.copy()
    mass[0] = 1e-6  # a free particle this light would dominate ω_max
    free = free.copy()
    free[0] = False
    exact = exact_largest_eigenvalue(positions, ends, stiffness, mass, free)
    omega = highest_frequency(positions.copy(), ends, stiffness, mass, free)
    assert 0.999 * exact <= omega ** 2 <= 1.1 * exact * (1 + 1e-6)
    assert omega ** 2 < 2.0 * stiffness[0] / 1e-6  # far below the pinned particle's own rate


def one_spring(omega):
    """Particle 0 pinned, particle 1 (1 kg) free on a spring of stiffness ω² along x."""
    return dict(positions=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
                ends=np.array([[0, 1]]), stiffness=np.array([omega ** 2]),
                mass=np.ones(2), free=np.array([False, True]))


def symplectic_limit(zeta):
    """Largest ωh of symplectic Euler on ẍ = −ω²x − 2ζω·ẋ: its step matrix has
    det = 1 − 2ζy and trace = 2 − 2ζy − y² (y = ωh); Jury's conditions |det| ≤ 1,
    1 − trace + det = y² ≥ 0 and 1 + trace + det ≥ 0 give y ≤ min(1/ζ, 2·(√(ζ² + 1) − ζ)),
    i.e. y ≤ 2 undamped."""
    return min(1.0 / zeta if zeta > 0 else math.inf, 2.0 * (math.sqrt(zeta ** 2 + 1) - zeta))


def test_auto_symplectic_step_stays_inside_omega_h_below_two():
    """docs/physics.md: undamped symplectic Euler is stable exactly for ωh ≤ 2; the auto step is
    ``safety`` times that, for ω_max a little above the spring's ω."""
    omega, safety = 250.0, 0.8
    step = choose_time_step("auto", FRAME, "symplectic", damping_time=0.0, contact_modes=[],
                            safety=safety, **one_spring(omega))
    assert omega <= step.omega_max <= math.sqrt(1.1) * omega * (1 + 1e-12)
    assert step.stable_dt * step.omega_max == pytest.approx(symplectic_limit(0.0), rel=1e-6)
    assert step.dt * omega <= 2.0 * safety
    assert step.dt * step.substeps_per_frame == pytest.approx(FRAME, rel=1e-14)
    assert FRAME / (step.substeps_per_frame - 1) > safety * step.stable_dt  # fewest substeps


def test_auto_explicit_euler_with_rayleigh_damping_is_limited_by_the_damping_time():
    """docs/physics.md: explicit Euler on a mode of ratio ζ < 1 is stable for ωh ≤ 2ζ; Rayleigh damping
    gives ζ = β·ω/2, so every underdamped mode allows exactly h ≤ β."""
    omega, damping_time = 100.0, 0.005  # ζ at ω_max ≈ 0.26
    step = choose_time_step("auto", FRAME, "euler", damping_time=damping_time, contact_modes=[],
                            safety=0.8, **one_spring(omega))
    assert step.stable_dt == pytest.approx(damping_time, rel=1e-6)
    assert step.dt <= 0.8 * damping_time


@pytest.mark.parametrize("contacts", [1, 2, 96])
def test_contacts_on_one_coordinate_add_their_springs_and_dampers(contacts):
    """n penalties on one coordinate, each k̂ = 10⁶ 1/s², a dashpot 2ζ√k̂ (ζ = 0.3) and a
    friction damper 2√k̂: ẍ = −n·k̂·x − n·2ζ√k̂·ẋ across the normal, u̇ = −n·2√k̂·u along it.
    ``ContactMode.oscillators`` gives the oscillators with exactly those rates, and the step
    bound is the tighter of theirs: for FB Euler the friction's (ζ = √n above ζ·√n), ωh ≤
    2(√(n + 1) − √n) at ω = √(n·k̂) (``symplectic_limit``)."""
    stiffness, ratio = 1e6, 0.3
    normal, friction = ContactMode(stiffness, ratio, contacts).oscillators()
    for (omega, zeta), damping_rate in ((normal, contacts * 2 * ratio * math.sqrt(stiffness)),
                                       (friction, contacts * 2 * math.sqrt(stiffness))):
        assert omega ** 2 == pytest.approx(contacts * stiffness, rel=1e-12)
        assert 2 * zeta * omega == pytest.approx(damping_rate, rel=1e-12)
    bound = contact_step_limit("symplectic", [ContactMode(stiffness, ratio, contacts)])
    assert bound == pytest.approx(symplectic_limit(math.sqrt(contacts))
                                  / math.sqrt(contacts * stiffness), rel=1e-6)


def test_auto_step_also_respects_the_contact_modes():
    """A stiff penalty contact (k̂ = 1e6 1/s², ζ = 0.5) adds k̂ to ω_max² and two modes at
    ω = √k̂: its normal spring (ζ = 0.5, y ≤ 1.236) and its friction damper (ζ = 1,
    y ≤ 2(√2 − 1) = 0.828), which is the binding one."""
    omega, contact = 10.0, 1e6
    step = choose_time_step("auto", FRAME, "symplectic", damping_time=0.0,
                            contact_modes=[ContactMode(contact, 0.5)], safety=0.8,
                            **one_spring(omega))
    assert omega ** 2 + contact <= step.omega_max ** 2 <= 1.1 * omega ** 2 + contact + 1e-6
    friction_limit = symplectic_limit(1.0) / math.sqrt(contact)
    assert friction_limit < symplectic_limit(0.5) / math.sqrt(contact)
    assert friction_limit < 2.0 / step.omega_max  # neither normal nor springs bind
    assert step.stable_dt == pytest.approx(friction_limit, rel=1e-6)


def test_auto_implicit_step_is_half_a_frame():
    step = choose_time_step("auto", FRAME, "implicit", damping_time=0.0, contact_modes=[],
                            safety=0.8, **one_spring(1e4))
    assert step.substeps_per_frame == 2
    assert step.dt == pytest.approx(FRAME / 2, rel=1e-15)
    assert step.stable_dt is None


def test_auto_implicit_step_keeps_the_pins_travel_off_the_linearisation_small():
    """h ≤ √(IMPLICIT_PIN_TRAVEL · ℓ_pin / a_pin), and the fewest substeps that keep it."""
    for acceleration, spacing in ((3.0, 0.02), (6.0, 0.02), (6.0, 0.01), (40.0, 0.005)):
        step = choose_time_step("auto", FRAME, "implicit", damping_time=0.0, contact_modes=[],
                                safety=0.8, pin_drive=lambda: (acceleration, spacing),
                                **one_spring(1e4))
        longest = math.sqrt(IMPLICIT_PIN_TRAVEL * spacing / acceleration)
        assert step.dt <= longest < FRAME / (step.substeps_per_frame - 1)
        assert step.report()["pin_acceleration"] == acceleration
        assert step.report()["pin_spacing"] == spacing


def test_the_pins_drive_goes_with_the_tempo_squared_and_the_spacing_and_sets_the_step():
    """The hula's waist pins: a ∝ tempo² (the dance's shape fixed, its clock faster) and ℓ_pin
    the spacing down the skirt, so the shipped 90 beats a minute at 64 × 28 keeps half a frame,
    while 140 beats a minute, or 90 on a mesh twice as fine, take a third; a still body
    carries pins that never accelerate."""
    def simulation(*overrides):
        return Simulation(load_scene("hula", overrides))
    usual, fast = simulation(), simulation("body.tempo=140")
    fine = simulation("cloth.resolution=[128, 56]")
    ratio = fast.time_step.pin_acceleration / usual.time_step.pin_acceleration
    assert ratio == pytest.approx((140 / 90) ** 2, rel=0.03)
    length = load_scene("hula").cloth.length
    assert usual.time_step.pin_spacing == pytest.approx(length / 27, rel=0.05)  # 28 rows
    assert fine.time_step.pin_spacing == pytest.approx(length / 55, rel=0.05)
    assert [s.time_step.substeps_per_frame for s in (usual, fast, fine)] == [2, 3, 3]
    assert simulation("body.motion=still").time_step.pin_acceleration == 0.0


def test_auto_explicit_euler_without_damping_is_refused():
    """Explicit Euler grows every undamped mode by 1 + (ωh)² per step: no step is stable."""
    with pytest.raises(InputError, match="euler.*damping"):
        choose_time_step("auto", FRAME, "euler", damping_time=0.0, contact_modes=[],
                         safety=0.8, **one_spring(50.0))


def test_a_requested_step_bypasses_the_estimate():
    step = choose_time_step(0.002, FRAME, "euler", damping_time=0.0, contact_modes=[],
                            safety=0.8, **one_spring(1e6))
    assert (step.substeps_per_frame, step.omega_max, step.stable_dt) == (17, None, None)


def rk4_limit_at_half_damping():
    """Largest ωh of RK4 on ẍ = −ω²x − ω·ẋ (ζ = 0.5): the root of |R(z)| = 1 on the ray of
    the eigenvalue z = y·(−1/2 + i·√3/2) (R the fourth-order Taylor polynomial, bisected)."""
    direction = complex(-0.5, math.sqrt(3) / 2)
    low, high = 1.0, 4.0
    for _ in range(80):
        z = 0.5 * (low + high) * direction
        grows = abs(1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24) > 1
        low, high = (low, 0.5 * (low + high)) if grows else (0.5 * (low + high), high)
    return low


@pytest.mark.parametrize("integrator, limit", [
    ("symplectic", symplectic_limit(1.0)),  # the friction damper binds (0.828 < 1.236)
    ("rk4", rk4_limit_at_half_damping()),  # the normal spring binds (2.623 < 2.785)
    ("euler", 1.0),  # ωh ≤ 2ζ: the normal spring at ζ = 0.5
])
def test_a_requested_step_is_split_until_the_bounding_modes_are_stable(integrator, limit):
    """Self-collision's penalty bounds a step given in seconds too (docs/physics.md, "Time
    step"): its modes at ω = √k̂ (ζ = 0.5 and the friction damper's ζ = 1) make the frame's
    substeps no longer than ``safety`` × the integrator's limit, which ``stable_dt`` reports;
    the request is kept, and the springs (ω = 10³ here, unstable for explicit Euler at any
    step) are not looked at. A request within the bound, and backward Euler, are not split."""
    stiffness, safety = 4e6, 0.8
    modes = dict(damping_time=0.0, contact_modes=[ContactMode(stiffness, 0.5)], safety=safety,
                 bounding_modes={"self_collision": [ContactMode(stiffness, 0.5)]},
                 **one_spring(1e3))
    step = choose_time_step(0.002, FRAME, integrator, **modes)
    bound = limit / math.sqrt(stiffness)
    assert step.stable_dt == pytest.approx(bound, rel=1e-6)
    assert step.requested == 0.002 and step.omega_max is None
    assert step.dt <= safety * bound * (1 + 1e-6) < 0.002
    assert step.dt * step.substeps_per_frame == pytest.approx(FRAME, rel=1e-14)
    assert FRAME / (step.substeps_per_frame - 1) > safety * step.stable_dt  # fewest substeps
    within = choose_time_step(0.5 * safety * bound, FRAME, integrator, **modes)
    assert within == fixed_time_step(0.5 * safety * bound, FRAME)
    # a bound below the request that adds no substep (1/30 s in 4 either way) splits nothing
    same = fixed_time_step(0.01, FRAME, stable=0.009 / safety, safety=safety)
    assert same == fixed_time_step(0.01, FRAME) and same.substeps_per_frame == 4
    assert choose_time_step(0.002, FRAME, "implicit", **modes) == fixed_time_step(0.002, FRAME)


def test_an_undamped_bounding_penalty_under_explicit_euler_is_refused():
    """Explicit Euler is stable at no step for an undamped mode: a one-line error naming the
    damping key, not a step of zero."""
    with pytest.raises(InputError, match="effects.self_collision.damping"):
        undamped = [ContactMode(1e6, 0.0)]
        choose_time_step(0.002, FRAME, "euler", damping_time=0.0, contact_modes=undamped,
                         safety=0.8, bounding_modes={"self_collision": undamped},
                         **one_spring(10.0))


@pytest.mark.parametrize("integrator, dt, retries, advised, not_advised", [
    ("implicit", "0.01", 0, "lower simulation.dt or set it to \"auto\"", "use integrator"),
    ("implicit", "auto", 0, "set simulation.dt below 0.0167 s", "set it to \"auto\""),
    ("implicit", "auto", 1, "set simulation.dt below 0.00833 s", "set it to \"auto\""),
    ("symplectic", "auto", 0, "use integrator = \"implicit\"", "[effects.damping]"),
])
def test_a_frame_past_the_guard_advises_what_the_integrator_can_change(integrator, dt, retries,
                                                                        advised, not_advised):
    """A frame past ``max_speed`` (set below any speed but the start's, 0) with no retries left
    ends the run in one ``UnstableError`` that names the frame and advises a smaller step (below
    the last one tried, when "auto" chose it: backward Euler's half frame, halved once by a
    retry), and the implicit integrator only to a run that does not use it already."""
    scene = load_scene("sheet", ("cloth.resolution=[6, 6]", f"simulation.integrator={integrator}",
                                 f"simulation.dt={dt}", "simulation.max_speed=1e-4",
                                 f"simulation.max_retries={retries}"))
    with pytest.raises(UnstableError) as failure:
        Simulation(scene).run(1)
    message = str(failure.value)
    assert "frame 1" in message and advised in message and not_advised not in message


def test_a_frame_stretched_past_redo_strain_is_redone_at_a_smaller_step():
    """With ``simulation.redo_strain`` below any strain, the first frame is redone at dt/2 (and
    dt/4, dt/8 while halving still changes the strain): the kept state is, bit for bit, that
    frame simulated at the smaller step kept, and the run's step comes back afterwards."""
    base = ("cloth.resolution=[6, 6]", "simulation.integrator=symplectic")  # dt "auto"
    guarded = Simulation(load_scene("sheet", base + ("simulation.redo_strain=1e-9",)))
    dt = guarded.time_step.dt
    record = guarded.run(1)
    halvings = record.frames[1].extra["strain_halvings"]
    assert halvings in (1, 2, 3) and guarded.time_step.dt == dt
    reference = Simulation(load_scene("sheet", base + (f"simulation.dt={dt / 2 ** halvings!r}",)))
    reference.run(1)
    assert reference.time_step.substeps_per_frame == \
        2 ** halvings * guarded.time_step.substeps_per_frame
    np.testing.assert_array_equal(guarded.positions(), reference.positions())
    unguarded = Simulation(load_scene("sheet", base))
    assert "strain_halvings" not in unguarded.run(1).frames[1].extra


def test_a_frame_sunk_past_redo_penetration_is_redone_at_a_smaller_step():
    """With ``simulation.redo_penetration`` below any depth, a sheet that starts with its lower
    edge 2 cm inside the ground has its first frame redone at dt/2 (and dt/4, dt/8 while halving
    still changes the depth): the kept state is, bit for bit, that frame simulated at the
    smaller step kept, the metrics report that state's depth, only the penetration guard counts a
    halving, and the run's step comes back afterwards."""
    base = ("cloth.resolution=[6, 6]", "simulation.integrator=symplectic",
            "effects.ground.height=0.62")  # the sheet hangs from 1.6 m to 0.6 m
    guarded = Simulation(load_scene("sheet", base + ("simulation.redo_penetration=1e-9",)))
    dt = guarded.time_step.dt
    frame = guarded.run(1).frames[1]
    halvings = frame.extra["penetration_halvings"]
    assert halvings in (1, 2, 3) and guarded.time_step.dt == dt
    assert "strain_halvings" not in frame.extra and "tunnelling_halvings" not in frame.extra
    reference = Simulation(load_scene("sheet", base + (f"simulation.dt={dt / 2 ** halvings!r}",)))
    reference_frame = reference.run(1).frames[1]
    np.testing.assert_array_equal(guarded.positions(), reference.positions())
    assert frame.max_penetration == reference_frame.max_penetration > 0.01


@pytest.mark.parametrize("mended_at, tunnelling, kept, crossings", [(8, 3, 6, 0),
                                                                    (128, 6, 6, 1)])
def test_a_frame_that_tunnelled_is_redone_while_it_does_down_to_a_64th_of_the_step(
        monkeypatch, mended_at, tunnelling, kept, crossings):
    """A frame that ends with more pairs of triangles through each other than it began with is
    redone at dt/2, dt/4, ... dt/64 while it still does (the crossings here counted as
    one at any step above dt/``mended_at``, none below). With ``redo_strain`` below any strain
    as well, and the strain (faked) halving with the step, so that each halving is worth
    another, the strain guard goes on ``REDO_HALVINGS`` past the tunnelling guard's last, at
    most to dt/64, and counts only its own halvings. The kept state is, bit for bit, that frame
    at the last step tried (the least strained of the tries without crossings, or else with the
    fewest), its crossings those of that try, and the run's step comes back afterwards. The
    effects are told of each tunnelling halving before each try, and of the run's step after
    the last."""
    base = ("cloth.resolution=[6, 6]", "simulation.integrator=symplectic")  # dt "auto"
    guarded = Simulation(load_scene("sheet", base + ("simulation.redo_strain=1e-9",)))
    dt = guarded.time_step.dt
    start = guarded.positions()

    def count(positions):  # none at the start, then one while the step is too long
        if np.array_equal(positions, start):
            return 0
        return int(guarded.time_step.dt > dt / mended_at * (1 + 1e-9))

    monkeypatch.setattr(guarded, "guards_crossings", True)
    monkeypatch.setattr(guarded.intersections, "count", count)
    monkeypatch.setattr(simulation_module, "largest_stretch_strain",
                        lambda model, x: guarded.time_step.dt)
    redone = []  # what the effects are told of each try (self-collision stiffens for it)
    monkeypatch.setattr(guarded.effects[0], "follow_redo", redone.append)
    frame = guarded.run(1).frames[1]
    assert frame.extra["tunnelling_halvings"] == tunnelling and guarded.time_step.dt == dt
    assert redone == [*range(1, tunnelling + 1), *[tunnelling] * (kept - tunnelling), 0]
    assert frame.extra["strain_halvings"] == kept
    assert frame.self_intersections == crossings
    reference = Simulation(load_scene("sheet", base + (f"simulation.dt={dt / 2 ** kept!r}",)))
    reference.run(1)
    np.testing.assert_array_equal(guarded.positions(), reference.positions())


@pytest.mark.parametrize("strains, began, kept, tries", [
    ((0.05, 0.09, 0.07, 0.06), None, 0, 4),  # worse at dt/2, on to dt/8, none better than dt
    ((0.05, 0.09, 0.02, 0.01), None, 3, 4),  # worse at dt/2, then best at dt/8: the last try
    ((0.05, 0.047, 0.01, 0.01), None, 1, 2),  # within REDO_GAIN of dt at dt/2 in a frame that
    # began stretched (faked as at dt: the garment's): no dt/4
    ((0.05, 0.052, 0.01, 0.01), None, 0, 2),  # the same, a little worse: dt's
    ((0.05, 0.047, 0.02, 0.01), 0.0, 3, 4),  # the same in a frame that began unstretched: on
    ((0.05, 0.047, 0.02, 0.01), 0.03, 3, 4),  # began stretched, but far less (0.047 > 0.033)
    # past RUBBER_STRAIN still at dt/8: on to dt/64, each halving gaining more than REDO_GAIN
    ((0.5, 0.4, 0.3, 0.2, 0.15, 0.12, 0.11), None, 6, 7),
])
@pytest.mark.parametrize("integrator", ["symplectic", "implicit"])
def test_the_best_try_of_a_redone_frame_is_kept(monkeypatch, strains, began, kept, tries,
                                                integrator):
    """A halving that leaves the strain within ``REDO_GAIN`` of the try before, either way, and
    no further than 1/``REDO_GAIN`` of the frame's start, is the last in a frame that began past
    ``redo_strain`` (``began``: the strain at its start, measured by the run where None); one
    that makes it worse past that goes on, to dt/8, or to dt/64 while the strain is past
    ``RUBBER_STRAIN``. The frame kept is the try with the least strain: when that is not the
    last, its end is put back, and the kept state is, bit for bit, that frame at that step (with
    what the integrator carries: the next frame goes on from it), its strain and halvings
    reported. Each try starts from the frame's start, the implicit integrator's warm start too.
    The strain is faked as a function of the step."""
    base = ("cloth.resolution=[6, 6]", f"simulation.integrator={integrator}")  # dt "auto"
    guarded = Simulation(load_scene("sheet", base + ("simulation.redo_strain=1e-9",)))
    dt = guarded.time_step.dt
    monkeypatch.setattr(simulation_module, "largest_stretch_strain", lambda model, x: strains[
        round(math.log2(dt / guarded.time_step.dt))])
    advance, steps = guarded.advance_frame, []
    monkeypatch.setattr(guarded, "advance_frame", lambda *args: (
        steps.append(guarded.time_step.dt), advance(*args))[1])
    if began is not None:
        monkeypatch.setattr(guarded, "_measured", {"strain": began})
    frame = guarded.run(1).frames[1]
    assert steps == [dt / 2 ** k for k in range(tries)] and guarded.time_step.dt == dt
    assert frame.extra["strain_halvings"] == kept and frame.max_strain == strains[kept]
    reference = Simulation(load_scene("sheet", base + (f"simulation.dt={dt / 2 ** kept!r}",)))
    reference.run(1)
    np.testing.assert_array_equal(guarded.positions(), reference.positions())
    for name, value in guarded.integrator.memory().items():  # the kept try's, not the last's
        np.testing.assert_array_equal(value, reference.integrator.memory()[name])


def test_a_smaller_step_that_blows_up_keeps_the_best_try_before_it(monkeypatch):
    """A redo at dt/4 that ends past ``blowup_strain`` (faked) is not the frame guard's to
    retry at half the run's step: the best try before it (dt, the least strain) is put back,
    bit for bit that frame at dt, and the run keeps its step."""
    base = ("cloth.resolution=[6, 6]", "simulation.integrator=symplectic")
    guarded = Simulation(load_scene("sheet", base + ("simulation.redo_strain=1e-9",)))
    dt = guarded.time_step.dt
    strains = (0.05, 0.09, 2.0)
    monkeypatch.setattr(simulation_module, "largest_stretch_strain", lambda model, x: strains[
        round(math.log2(dt / guarded.time_step.dt))])
    record = guarded.run(1)
    assert record.retries == 0 and guarded.time_step.dt == dt
    assert record.frames[1].max_strain == 0.05 and record.frames[1].extra["strain_halvings"] == 0
    reference = Simulation(load_scene("sheet", base + (f"simulation.dt={dt!r}",)))
    reference.run(1)
    np.testing.assert_array_equal(guarded.positions(), reference.positions())


def test_a_try_that_tunnels_less_is_kept_before_one_that_stretches_less(monkeypatch):
    """Crossing pairs come first: a frame that crosses at dt and not at smaller steps (counted
    as faked), stretched least at dt and more at each smaller step, keeps its try at dt/2 (put
    back), the effects told of the run's step after it."""
    base = ("cloth.resolution=[6, 6]", "simulation.integrator=symplectic")  # dt "auto"
    guarded = Simulation(load_scene("sheet", base + ("simulation.redo_strain=1e-9",)))
    dt = guarded.time_step.dt
    start = guarded.positions()
    monkeypatch.setattr(guarded, "guards_crossings", True)
    monkeypatch.setattr(guarded.intersections, "count", lambda positions: int(
        not np.array_equal(positions, start) and guarded.time_step.dt == dt))
    monkeypatch.setattr(simulation_module, "largest_stretch_strain", lambda model, x: {
        dt: 0.01, dt / 2: 0.05, dt / 4: 0.09, dt / 8: 0.095, dt / 16: 0.097}[guarded.time_step.dt])
    redone = []
    monkeypatch.setattr(guarded.effects[0], "follow_redo", redone.append)
    frame = guarded.run(1).frames[1]
    # dt/2 ... dt/16 (the strain guard's three halvings past the tunnelling one; the frame began
    # at 0.01, so 0.095 within REDO_GAIN of dt/4's 0.09 is not the garment's), then the run's
    assert redone == [1, 1, 1, 1, 0]
    assert frame.extra["tunnelling_halvings"] == 1 and frame.extra["strain_halvings"] == 1
    assert frame.self_intersections == 0 and frame.max_strain == 0.05
    reference = Simulation(load_scene("sheet", base + (f"simulation.dt={dt / 2!r}",)))
    reference.run(1)
    np.testing.assert_array_equal(guarded.positions(), reference.positions())


def test_each_guard_counts_only_the_halvings_it_asked_for(monkeypatch):
    """With both redo guards on (a self-collision scene with ``redo_strain``), a frame redone
    because it stretched past ``redo_strain`` counts as a strain halving, not a tunnelling one
    (the crossings here counted as none, so the tunnelling guard never asks)."""
    base = ("cloth.resolution=[6, 6]", "simulation.integrator=symplectic",
            "simulation.redo_strain=1e-9")
    guarded = Simulation(load_scene("sheet", base))
    monkeypatch.setattr(guarded, "guards_crossings", True)
    monkeypatch.setattr(guarded.intersections, "count", lambda positions: 0)
    redone = []
    monkeypatch.setattr(guarded.effects[0], "follow_redo", redone.append)
    extra = guarded.run(1).frames[1].extra
    assert extra["strain_halvings"] in (1, 2) and extra["tunnelling_halvings"] == 0
    assert set(redone) <= {0}  # a strain halving does not stiffen the effects
