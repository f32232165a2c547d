"""``uploads.upload`` fills fields exactly as ``from_numpy`` does, in one launch, and an
``UploadBatch`` holds its copies until sent; a ``StateSet`` reads, writes and copies its states
as ``to_numpy``, ``from_numpy`` and ``copy_from`` do; ``gather.sweep_rows`` merges the springs'
and the coupled effects' rows for the Gauss–Seidel sweeps."""

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


def test_sweep_rows_fold_coupled_entries_into_springs_and_split_each_row_in_four_runs():
    """``gather.sweep_rows`` on a small spring list (a pair joined by two springs) and two
    coupled effects: every spring entry is listed once; the coupled entries' sums Σ H and Σ β·H
    per pair are what the effects give, each on the row's first spring to that neighbour or on
    an entry of its own; a row's runs are lower with a spring (in gather order), lower without
    (neighbours ascending), then the same for the upper neighbours."""
    from taichi_cloth.gather import gather_lists, sweep_rows
    count = 5
    springs = np.array([[0, 2], [1, 2], [2, 3], [0, 1], [3, 1], [2, 0]])
    start, _, neighbor = gather_lists(springs, count)
    rng = np.random.default_rng(3)
    coupled, expected = [], np.zeros((count, count, 2))
    for damping_time in (0.5, 0.25):
        dense = np.triu(rng.standard_normal((count, count)) * (rng.random((count, count)) < 0.6),
                        1)
        dense[0, 2] = 1.0  # on the pair that two springs join: folded into the first
        dense += dense.T
        row_start = np.concatenate([[0], np.cumsum((dense != 0).sum(1))]).astype(np.int32)
        rows, columns = np.nonzero(dense)
        coupled.append((row_start, columns.astype(np.int32), dense[rows, columns], damping_time))
        expected[..., 0] += dense
        expected[..., 1] += damping_time * dense
    row_start, bounds, entry_neighbor, entry_spring, sums = sweep_rows(start, neighbor, coupled,
                                                                     count)
    assert sorted(entry_spring[entry_spring >= 0]) == list(range(len(neighbor)))
    listed = np.zeros_like(expected)
    for i in range(count):
        entries = range(row_start[i], row_start[i + 1])
        runs = np.split(np.array(entries, int), bounds[i] - row_start[i])
        for run, (upper, with_spring) in zip(runs, [(0, 1), (0, 0), (1, 1), (1, 0)]):
            assert all((entry_neighbor[s] > i) == upper for s in run)
            assert all((entry_spring[s] >= 0) == with_spring for s in run)
            key = entry_spring[run] if with_spring else entry_neighbor[run]
            assert list(key) == sorted(key)
        for s in entries:
            j = entry_neighbor[s]
            if entry_spring[s] >= 0:
                assert neighbor[entry_spring[s]] == j
                assert start[i] <= entry_spring[s] < start[i + 1]
                first = start[i] + list(neighbor[start[i]:start[i + 1]]).index(j)
                assert entry_spring[s] == first or not sums[s].any()
            listed[i, j] += sums[s]
    np.testing.assert_allclose(listed, expected, rtol=1e-12, atol=1e-15)
    assert (entry_spring >= 0).sum() == len(neighbor)


def test_sweep_rows_refuse_a_coupled_row_that_holds_its_diagonal():
    """The coupled effects give off-diagonal entries only (their diagonals go to A_ii); one on
    the diagonal would otherwise be filed as a neighbour of its own row."""
    from taichi_cloth.gather import gather_lists, sweep_rows
    start, _, neighbor = gather_lists(np.array([[0, 1]]), 2)
    diagonal = (np.array([0, 1, 1], np.int32), np.array([0], np.int32), np.array([1.0]), 0.0)
    with pytest.raises(ValueError, match="diagonal"):
        sweep_rows(start, neighbor, [diagonal], 2)
