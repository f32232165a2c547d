"""``uploads.upload`` fills fields exactly as ``from_numpy`` does, in one launch, and an
``UploadBatch`` holds its copies until sent; a ``StateSet`` reads, writes and copies its states
as ``to_numpy``, ``from_numpy`` and ``copy_from`` do; ``gather.side_lists`` splits CSR rows for
the Gauss–Seidel sweeps."""

import numpy as np
import pytest
import taichi as ti

from taichi_cloth.physics.model import State, StateSet
from taichi_cloth.uploads import UploadBatch, upload


def test_a_batch_of_fields_holds_the_bits_from_numpy_gives():
    rng = np.random.default_rng(3)
    arrays = {"f32": rng.standard_normal(40) * 1e3, "f64": rng.standard_normal(7),
              "vectors": rng.standard_normal((5, 6, 3)), "lanes": rng.integers(0, 2, (3, 4, 16)),
              "ints": rng.integers(-9, 9, 11).astype(np.int32), "flags": rng.random(6) < 0.5}
    fields = {"f32": ti.field(ti.f32, 40), "f64": ti.field(ti.f64, 7),
              "vectors": ti.Vector.field(3, ti.f32, (5, 6)),
              "lanes": ti.Vector.field(16, ti.i32, (3, 4)), "ints": ti.field(ti.i32, 11),
              "flags": ti.field(ti.i32, 6)}
    references = {"f32": ti.field(ti.f32, 40), "vectors": ti.Vector.field(3, ti.f32, (5, 6))}
    upload([(fields[name], arrays[name]) for name in fields])
    references["f32"].from_numpy(arrays["f32"].astype(np.float32))
    references["vectors"].from_numpy(arrays["vectors"].astype(np.float32))
    for name, reference in references.items():  # f64 → f32 rounds as NumPy's astype does
        assert np.array_equal(fields[name].to_numpy(), reference.to_numpy())
    for name in ("f64", "lanes", "ints", "flags"):
        held = fields[name].to_numpy()
        assert np.array_equal(held, arrays[name].astype(held.dtype))


def test_a_state_set_moves_the_bits_to_numpy_from_numpy_and_copy_from_move():
    rng = np.random.default_rng(5)
    x, v = rng.standard_normal((7, 3)) * 1e3, rng.standard_normal((7, 3))
    states = StateSet([State(7, ti.f32) for _ in range(3)])
    reference = State(7, ti.f32)
    states.write(states.members[1], x, v)  # f64 → f32 rounds as NumPy's astype does
    reference.x.from_numpy(x.astype(np.float32))
    reference.v.from_numpy(v.astype(np.float32))
    read = states.read(states.members[1])
    assert all(array.dtype == np.float64 for array in read)
    assert np.array_equal(read[0], reference.x.to_numpy())
    assert np.array_equal(read[1], reference.v.to_numpy())
    states.copy(states.members[2], states.members[1])
    for member, expected in ((states.members[2], read), (states.members[0], (0 * x, 0 * v))):
        for held, array in zip(states.read(member), expected):
            assert np.array_equal(held, array)
    with pytest.raises(ValueError, match="not one of its members"):
        states.read(reference)
    with pytest.raises(ValueError, match="shapes"):  # nothing read past a short array's end
        states.write(states.members[0], x[:6], v[:6])


def test_matrix_and_zero_dimensional_fields_are_filled_component_by_component():
    rotation = np.arange(9.0).reshape(3, 3) / 7.0
    blocks = np.random.default_rng(4).standard_normal((4, 2, 3))
    fields = (ti.Matrix.field(3, 3, ti.f64, ()), ti.Matrix.field(2, 3, ti.f32, 4),
              ti.field(ti.i32, ()))
    upload([(fields[0], rotation), (fields[1], blocks), (fields[2], np.array(7))])
    assert np.array_equal(fields[0].to_numpy(), rotation)
    assert np.array_equal(fields[1].to_numpy(), blocks.astype(np.float32))
    assert fields[2][None] == 7


def test_a_batch_copies_nothing_until_sent_then_everything_at_once():
    early, late = ti.field(ti.f32, 3), ti.field(ti.i32, 2)
    batch = UploadBatch()
    batch.add([(early, np.array([1.0, 2.0, 3.0]))])
    batch.add([(late, np.array([4, 5]))])
    assert not early.to_numpy().any() and not late.to_numpy().any()
    batch.send()
    assert early.to_numpy().tolist() == [1.0, 2.0, 3.0] and late.to_numpy().tolist() == [4, 5]
    after = ti.field(ti.f32, 1)
    batch.add([(after, np.array([6.0]))])  # once sent, a copy is made at once
    assert after[0] == 6.0


def test_an_array_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=r"\(4,\) for a field of \(5,\)"):
        upload([(ti.field(ti.f32, 5), np.zeros(4))])


def test_side_lists_split_each_row_at_its_diagonal_and_keep_the_list_order():
    """``gather.side_lists`` on a small spring list: each particle's entries to lower
    neighbours, then to higher ones, each half in gather order."""
    from taichi_cloth.gather import gather_lists, side_lists
    springs = np.array([[0, 2], [1, 2], [2, 3], [0, 1], [3, 1]])
    start, _, neighbor = gather_lists(springs, 4)
    entry, split = side_lists(start, neighbor)
    for i in range(4):
        lower = [int(neighbor[k]) for k in entry[start[i]:split[i]]]
        upper = [int(neighbor[k]) for k in entry[split[i]:start[i + 1]]]
        in_order = [int(j) for j in neighbor[start[i]:start[i + 1]]]
        assert lower == [j for j in in_order if j < i]
        assert upper == [j for j in in_order if j > i]
