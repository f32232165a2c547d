"""Checkpoints for --resume: what is saved comes back bit for bit, and a checkpoint that does not
belong to the scene (other settings, none at all, a damaged file) is refused with an InputError
naming --resume."""

import dataclasses
import struct
import zipfile

import numpy as np
import pytest

from taichi_cloth.config.scene import load_scene
from taichi_cloth.errors import InputError
from taichi_cloth.output.checkpoint import (CHECKPOINT_NAME, Checkpoint, load_checkpoint,
                                            save_checkpoint, scene_fingerprint)
from taichi_cloth.output.run import read_previous_stats
from taichi_cloth.physics.snapshot import Snapshot

RESOLUTION = "cloth.resolution=[4, 4]"


@pytest.fixture(scope="module")
def scene():
    return load_scene("sheet", (RESOLUTION,))


def random_checkpoint(scene, seed=0) -> Checkpoint:
    """A checkpoint of a 16-particle sheet in awkward values: random doubles (full mantissas),
    a halved step, f32 and integer memory arrays."""
    rng = np.random.default_rng(seed)
    snapshot = Snapshot(
        positions=rng.standard_normal((16, 3)), velocities=rng.standard_normal((16, 3)) * 1e-7,
        dt=1.0 / 30.0 / 34.0, substeps_per_frame=34,
        integrator_memory={"guess": rng.standard_normal((16, 3)).astype(np.float32),
                           "velocity_change": rng.standard_normal((16, 3)),
                           "counts": np.arange(5, dtype=np.int32)},
        effect_memory={"self_collision.found": rng.integers(-3, 99, (16, 4)).astype(np.int32),
                       "self_collision.rotation": rng.standard_normal((3, 3)).astype(np.float32),
                       "self_collision.committed": np.array(1, np.int32)})
    return Checkpoint(next_frame=7, snapshot=snapshot, retries=2,
                      fingerprint=scene_fingerprint(scene),
                      cg_iterations=rng.integers(1, 50, 12))


def test_round_trip_is_bit_for_bit(tmp_path, scene):
    saved = random_checkpoint(scene)
    save_checkpoint(tmp_path, saved)
    loaded = load_checkpoint(tmp_path, scene)
    assert (loaded.next_frame, loaded.retries, loaded.fingerprint) == (7, 2, saved.fingerprint)
    assert loaded.snapshot.dt == saved.snapshot.dt  # the exact double, not a rounded one
    assert loaded.snapshot.substeps_per_frame == 34
    for name in ("positions", "velocities"):
        expected, got = getattr(saved.snapshot, name), getattr(loaded.snapshot, name)
        assert got.dtype == expected.dtype
        assert got.tobytes() == expected.tobytes()
    for memory in ("integrator_memory", "effect_memory"):
        expected_memory, loaded_memory = (getattr(c.snapshot, memory) for c in (saved, loaded))
        assert set(loaded_memory) == set(expected_memory)
        for name, expected in expected_memory.items():
            got = loaded_memory[name]
            assert (got.dtype, got.shape) == (expected.dtype, expected.shape)
            assert got.tobytes() == expected.tobytes()
    np.testing.assert_array_equal(loaded.cg_iterations, saved.cg_iterations)


def test_empty_integrator_memory_stays_empty(tmp_path, scene):
    """Explicit integrators (and effects without history) carry nothing between steps: no
    memory key appears from nowhere."""
    saved = random_checkpoint(scene)
    bare = Checkpoint(saved.next_frame, Snapshot(saved.snapshot.positions,
                                                 saved.snapshot.velocities, saved.snapshot.dt,
                                                 saved.snapshot.substeps_per_frame, {}),
                      saved.retries, saved.fingerprint, np.zeros(0, dtype=np.int64))
    save_checkpoint(tmp_path, bare)
    loaded = load_checkpoint(tmp_path, scene)
    assert loaded.snapshot.integrator_memory == {} and loaded.snapshot.effect_memory == {}
    assert loaded.cg_iterations.size == 0


def test_saving_again_replaces_the_checkpoint(tmp_path, scene):
    save_checkpoint(tmp_path, random_checkpoint(scene, seed=1))
    newer = random_checkpoint(scene, seed=2)
    save_checkpoint(tmp_path, newer)
    assert [p.name for p in tmp_path.iterdir()] == [CHECKPOINT_NAME]  # no temporary left
    loaded = load_checkpoint(tmp_path, scene)
    assert loaded.snapshot.positions.tobytes() == newer.snapshot.positions.tobytes()


@pytest.mark.parametrize("other", [
    ("cloth.resolution=[5, 4]",),
    (RESOLUTION, "simulation.integrator=rk4"),
    (RESOLUTION, "effects.drag=false"),
])
def test_checkpoint_of_other_settings_is_refused(tmp_path, scene, other):
    save_checkpoint(tmp_path, random_checkpoint(scene))
    changed = load_scene("sheet", other)
    assert scene_fingerprint(changed) != scene_fingerprint(scene)
    with pytest.raises(InputError, match="--resume"):
        load_checkpoint(tmp_path, changed)


def test_fingerprint_is_the_same_for_the_same_settings(scene):
    assert scene_fingerprint(load_scene("sheet", (RESOLUTION,))) == scene_fingerprint(scene)


def test_missing_checkpoint_is_refused(tmp_path, scene):
    with pytest.raises(InputError, match="--resume.*no checkpoint.npz"):
        load_checkpoint(tmp_path, scene)


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_damaged_checkpoint_is_refused_with_an_input_error(tmp_path, scene, damage):
    """A checkpoint cut short (the disk filled up, a copy interrupted) or overwritten is refused
    like any other bad input (exit code 2), not with numpy's own error."""
    save_checkpoint(tmp_path, random_checkpoint(scene))
    path = tmp_path / CHECKPOINT_NAME
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2] if damage == "truncated"
                     else np.random.default_rng(3).bytes(len(data)))
    with pytest.raises(InputError, match="--resume"):
        load_checkpoint(tmp_path, scene)


def test_a_flipped_byte_in_the_positions_is_never_loaded_silently(tmp_path, scene):
    """One bit of rot inside the stored positions: the zip CRC catches it, so a resumed run can
    never go on from a silently wrong state; it is refused as a damaged file (exit code 2)."""
    save_checkpoint(tmp_path, random_checkpoint(scene))
    path = tmp_path / CHECKPOINT_NAME
    with zipfile.ZipFile(path) as archive:
        entry = archive.getinfo("positions.npy")
    data = bytearray(path.read_bytes())
    name_length, extra_length = struct.unpack("<HH", data[entry.header_offset + 26:
                                                          entry.header_offset + 30])
    payload = entry.header_offset + 30 + name_length + extra_length
    data[payload + entry.compress_size - 1] ^= 0x01  # the last byte of the last coordinate
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="--resume.*damaged"):
        load_checkpoint(tmp_path, scene)


@pytest.mark.parametrize("change, words", [
    (lambda c: dataclasses.replace(c, snapshot=dataclasses.replace(
        c.snapshot, positions=np.full((16, 3), np.nan))), "non-finite state"),
    (lambda c: dataclasses.replace(c, next_frame=-5), "impossible frame"),
    (lambda c: dataclasses.replace(c, snapshot=dataclasses.replace(c.snapshot, dt=0.0)),
     "impossible frame"),
    (lambda c: dataclasses.replace(c, snapshot=dataclasses.replace(
        c.snapshot, integrator_memory={"guess": np.full(3, np.inf)})), "non-finite solver"),
])
def test_a_well_formed_but_unusable_checkpoint_is_refused(tmp_path, scene, change, words):
    """Written whole (its checksum holds) but holding what no run can continue from."""
    save_checkpoint(tmp_path, change(random_checkpoint(scene)))
    with pytest.raises(InputError, match=f"--resume.*{words}"):
        load_checkpoint(tmp_path, scene, 16)


def test_other_particle_counts_and_outputs_are_refused(tmp_path, scene):
    save_checkpoint(tmp_path, dataclasses.replace(random_checkpoint(scene), outputs="png 64x48"))
    with pytest.raises(InputError, match="--resume.*16 particles"):
        load_checkpoint(tmp_path, scene, 25)
    with pytest.raises(InputError, match="--resume.*other outputs"):
        load_checkpoint(tmp_path, scene, 16, "png 640x480")
    assert load_checkpoint(tmp_path, scene, 16, "png 64x48").outputs == "png 64x48"


@pytest.mark.parametrize("text", [None, "{\"per_frame\": [{\"frame\": 0}", "[]",
                                  "{\"per_frame\": [{\"frame\": 0}]}"])
def test_resume_refuses_a_missing_truncated_or_short_stats_file(tmp_path, text):
    """The interrupted run's stats.json must hold the frames the checkpoint continues (here 3)."""
    if text is not None:
        (tmp_path / "stats.json").write_text(text)
    with pytest.raises(InputError, match="--resume.*stats.json"):
        read_previous_stats(tmp_path, 3)
