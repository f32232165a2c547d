"""Filling many fields from NumPy in one kernel launch.

``field.from_numpy`` launches a kernel of Taichi's own, compiled once per field: a simulation's
few dozen fields cost as many kernel builds at start-up (each loaded from the offline cache and
linked, ~20–45 ms on the 2-core machine). ``upload`` copies a whole batch of scalar and vector
fields in one kernel, compiled once per batch: every real value travels as float64 and is
rounded to the field's type in the kernel (round to nearest, as NumPy's ``astype`` does, so the
fields hold the same bits as after ``from_numpy``), every integer as int32.
"""

import numpy as np
import taichi as ti


@ti.kernel
def _copy(layout: ti.template(), reals: ti.types.ndarray(dtype=ti.f64, ndim=1),
          integers: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """For each (field, offset, strides, width, integer) of ``layout``: every element of the
    field (its ``width`` components, 0 for a scalar field) from the flat array at offset + Σ
    index·stride (C order)."""
    for k in ti.static(range(len(layout))):
        field, offset, strides, width, integer = ti.static(layout[k])
        for index in ti.grouped(field):
            flat = offset
            for d in ti.static(range(len(strides))):
                flat += index[d] * strides[d]
            if ti.static(width == 0):
                if ti.static(integer):
                    field[index] = integers[flat]
                else:
                    field[index] = ti.cast(reals[flat], field.dtype)
            else:
                for c in ti.static(range(width)):
                    if ti.static(integer):
                        field[index][c] = integers[flat + c]
                    else:
                        field[index][c] = ti.cast(reals[flat + c], field.dtype)


def upload(pairs) -> None:
    """Copy each (field, array) of ``pairs`` into its field (scalar or vector fields of any
    shape; the array of the field's shape, then the vector's; integer and boolean fields from
    integer or boolean arrays) in one kernel launch."""
    reals, integers, layout = [], [], []
    sizes = {True: 0, False: 0}
    for field, array in pairs:
        array = np.asarray(array)
        width = field.n if hasattr(field, "n") else 0
        if width and field.m != 1:
            raise ValueError("upload: matrix fields are not supported, use from_numpy")
        expected = field.shape + ((width,) if width else ())
        if array.shape != expected:
            raise ValueError(f"upload: an array of shape {array.shape} for a field of {expected}")
        integer = bool(np.issubdtype(array.dtype, np.integer) or array.dtype == np.bool_)
        element = max(width, 1)
        strides = tuple(int(np.prod(field.shape[d + 1:], dtype=np.int64)) * element
                        for d in range(len(field.shape)))
        (integers if integer else reals).append(array.ravel())
        layout.append((field, sizes[integer], strides, width, integer))
        sizes[integer] += array.size
    _copy(tuple(layout),
          np.concatenate(reals).astype(np.float64) if reals else np.zeros(1),
          np.concatenate(integers).astype(np.int32) if integers else np.zeros(1, np.int32))
