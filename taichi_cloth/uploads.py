"""Filling many fields from NumPy in one kernel launch.

``field.from_numpy`` launches a kernel of Taichi's own, compiled once per field: a simulation's
few dozen fields cost as many kernel builds at start-up (each loaded from the offline cache and
linked, ~20–45 ms on the 2-core machine). ``upload`` copies a whole batch of scalar, vector and
matrix fields in one kernel, compiled once per batch: every real value travels as float64 and is
rounded to the field's type in the kernel (round to nearest, as NumPy's ``astype`` does, so the
fields hold the same bits as after ``from_numpy``), every integer as int32. Even so each launch
costs ~40 ms to load at start-up, so a simulation gathers all of its copies in one
``UploadBatch`` (the model's) and sends them together once every field is allocated (which also
keeps its fields in one SNode tree).
"""

import warnings

import numpy as np
import taichi as ti


@ti.kernel
def _copy(layout: ti.template(), reals: ti.types.ndarray(dtype=ti.f64, ndim=1),
          integers: ti.types.ndarray(dtype=ti.i32, ndim=1), longest: ti.i32):
    """For each (field, offset, components, integer) of ``layout``: element e (C order) of the
    field, its ``components`` values (1 for a scalar field, n·m of a matrix in row order), from
    the flat array at offset + e·components. One loop over the elements of the longest field
    serves every field (a loop per field made a kernel that took ~4× as long to load from the
    offline cache), and each field's element is one store of a whole scalar, vector or matrix
    written out here, without a function inlined per component (Taichi parses and transforms
    an inlined function again at every call: 135 of them for the 42 fields of ``hula`` took
    most of its 0.45 s upload at start-up)."""
    for element in range(longest):
        for k in ti.static(range(len(layout))):
            field, offset, components, integer = ti.static(layout[k])
            if element < ti.static(field_size(field)):
                flat = offset + element * components
                width = ti.static(vector_width(field))
                if ti.static(width == 0):
                    _put(field, element, integers[flat] if ti.static(integer) else
                         ti.cast(reals[flat], field.dtype))
                elif ti.static(width == 1 and integer):
                    _put(field, element, ti.Vector([integers[flat + r]
                                                    for r in ti.static(range(field.n))]))
                elif ti.static(width == 1):
                    _put(field, element, ti.Vector([ti.cast(reals[flat + r], field.dtype)
                                                    for r in ti.static(range(field.n))]))
                elif ti.static(integer):
                    _put(field, element, ti.Matrix([[integers[flat + r * width + c]
                                                     for c in ti.static(range(width))]
                                                    for r in ti.static(range(field.n))]))
                else:
                    _put(field, element, ti.Matrix([[ti.cast(reals[flat + r * width + c],
                                                              field.dtype)
                                                     for c in ti.static(range(width))]
                                                    for r in ti.static(range(field.n))]))


@ti.func
def _put(field: ti.template(), element, value: ti.template()):
    """Element ``element`` (C order) of ``field`` = value (a scalar, vector or matrix)."""
    shape = ti.static(field.shape)
    if ti.static(len(shape) == 0):
        field[None] = value
    else:
        field[ti.Vector([element // ti.static(stride(shape, d)) % ti.static(shape[d])
                         for d in ti.static(range(len(shape)))])] = value


def vector_width(field) -> int:
    """Columns of a field's element: 0 for a scalar field, 1 for a vector, m for an n × m
    matrix."""
    return field.m if hasattr(field, "n") else 0


def stride(shape: tuple, axis: int) -> int:
    """Elements of a C-order array of ``shape`` between two neighbours along ``axis``."""
    return int(np.prod(shape[axis + 1:], dtype=np.int64))


def field_size(field) -> int:
    """The number of elements of a field (the product of its shape; 1 for a 0-d field)."""
    return int(np.prod(field.shape, dtype=np.int64))


def upload(pairs) -> None:
    """Copy each (field, array) of ``pairs`` into its field (scalar, vector or matrix fields of
    any shape, 0-d included; the array of the field's shape, then the element's; integer and
    boolean fields from integer or boolean arrays) in one kernel launch."""
    reals, integers, layout = [], [], []
    sizes = {True: 0, False: 0}
    for field, array in pairs:
        array = np.asarray(array)
        element = (field.n,) if hasattr(field, "n") and field.m == 1 else \
            (field.n, field.m) if hasattr(field, "n") else ()
        expected = tuple(field.shape) + element
        if array.shape != expected:
            raise ValueError(f"upload: an array of shape {array.shape} for a field of {expected}")
        integer = bool(np.issubdtype(array.dtype, np.integer) or array.dtype == np.bool_)
        (integers if integer else reals).append(array.ravel())
        layout.append((field, sizes[integer], int(np.prod(element, dtype=np.int64)), integer))
        sizes[integer] += array.size
    if not layout:
        return
    with warnings.catch_warnings():  # a branch per field is the design: unrolled on purpose
        warnings.filterwarnings("ignore", "You are unrolling", SyntaxWarning)
        _copy(tuple(layout),
              np.concatenate(reals).astype(np.float64) if reals else np.zeros(1),
              np.concatenate(integers).astype(np.int32) if integers else np.zeros(1, np.int32),
              max(field_size(field) for field, _ in pairs))


class UploadBatch:
    """Copies gathered until ``send``, then made in one ``upload`` (one kernel launch, after
    every field of the batch's owner is allocated); once sent, a copy added is made at once. A
    field written outside the batch before it is sent (a track set by hand) is overwritten by
    the batch's copy at ``send``: send first (``tests/systems.assemble`` does)."""

    def __init__(self):
        self._pairs = []
        self.sent = False

    def add(self, pairs) -> None:
        """Copy each (field, array) of ``pairs`` into its field (``upload``): at ``send``, or
        now if the batch was sent."""
        if self.sent:
            upload(pairs)
        else:
            self._pairs.extend(pairs)

    def send(self) -> None:
        """Make every copy gathered so far, in one launch."""
        pairs, self._pairs, self.sent = self._pairs, [], True
        upload(pairs)
