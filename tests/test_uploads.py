"""``uploads.upload`` fills fields exactly as ``from_numpy`` does, in one launch."""

import numpy as np
import pytest
import taichi as ti

from taichi_cloth.uploads import upload


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


def test_an_array_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=r"\(4,\) for a field of \(5,\)"):
        upload([(ti.field(ti.f32, 5), np.zeros(4))])
