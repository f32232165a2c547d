"""A uniform grid of points hashed into buckets, rebuilt inside a kernel (no Python per step): the
broad phase of self-collision (``effects/self_collision.py``).

``build(cell_size)`` files each of the ``count`` points (``point`` and its ``kind``, filled by the
caller) under its cell ⌊p / cell_size⌋ and kind (points of different kinds in one cell go to
different buckets, so a query for one kind does not walk the others): bucket counts by atomic adds, a serial prefix sum, then each point finds its
slot as the bucket's start plus the number of points of lower index in the same bucket, so every
bucket lists its points in index order whatever the threads did (a loop over a bucket then sums
in a fixed order: bit-reproducible on the CPU). A query visits the 27 cells around a cell and keeps
the points whose cell (and kind) is the visited one (two cells may share a bucket).
"""

import taichi as ti

BUCKETS_PER_POINT = 2
KIND_OFFSET = 1000003  # cells a kind's grid is shifted along x in the hash (kilometres of cloth)


@ti.func
def hash_cell(cell, bucket_count) -> ti.i32:
    """The bucket in [0, bucket_count) of a grid cell (three integer indices): the spatial hash
    of Teschner et al. (2003, "Optimized spatial hashing for collision detection of deformable
    objects"), a sum of the indices times three large primes, in 64-bit integers."""
    code = ti.cast(cell[0], ti.i64) * 73856093 + ti.cast(cell[1], ti.i64) * 19349663 \
        + ti.cast(cell[2], ti.i64) * 83492791
    bucket = code % bucket_count
    if bucket < 0:
        bucket += bucket_count
    return ti.cast(bucket, ti.i32)


@ti.data_oriented
class SpatialHash:
    """``count`` points [m] (``point``) filed by grid cell (module docstring)."""

    def __init__(self, count: int, real):
        self.count = count
        self.bucket_count = max(1, BUCKETS_PER_POINT * count)
        self.point = ti.Vector.field(3, real, count)
        self.kind = ti.field(ti.i32, count)  # which kind of point (the caller's numbering)
        self.cell = ti.Vector.field(3, ti.i32, count)
        self.bucket_start = ti.field(ti.i32, self.bucket_count + 1)
        self.bucket_fill = ti.field(ti.i32, self.bucket_count)
        self.unsorted = ti.field(ti.i32, count)
        self.filed = ti.field(ti.i32, count)  # the points, bucket by bucket, each in index order

    @ti.func
    def bucket(self, cell, kind) -> ti.i32:
        """The bucket of a grid cell's points of one kind (``hash_cell`` of the cell shifted by
        ``KIND_OFFSET`` cells per kind)."""
        return hash_cell(cell + ti.Vector([kind * KIND_OFFSET, 0, 0]), self.bucket_count)

    @ti.func
    def point_bucket(self, i) -> ti.i32:
        """The bucket point i is filed in."""
        return self.bucket(self.cell[i], self.kind[i])

    @ti.func
    def cell_of(self, position, cell_size):
        """The grid cell of a position [m] for cells of ``cell_size`` [m]."""
        return ti.cast(ti.floor(position / cell_size), ti.i32)

    @ti.func
    def build(self, cell_size, when: ti.template()):
        """File every point under its cell of ``cell_size`` [m] (module docstring), when the 0-D
        field ``when`` is nonzero (the loops stay top-level, hence parallel)."""
        for b in range(self.bucket_count):
            if when[None]:
                self.bucket_fill[b] = 0
        for i in range(self.count):
            if when[None]:
                self.cell[i] = self.cell_of(self.point[i], cell_size)
                ti.atomic_add(self.bucket_fill[self.point_bucket(i)], 1)
        ti.loop_config(serialize=True)
        for b in range(self.bucket_count):
            if when[None]:
                self.bucket_start[b + 1] = self.bucket_start[b] + self.bucket_fill[b]
                self.bucket_fill[b] = self.bucket_start[b]
        for i in range(self.count):
            if when[None]:
                self.unsorted[ti.atomic_add(self.bucket_fill[self.point_bucket(i)], 1)] = i
        for i in range(self.count):
            if when[None]:
                b = self.point_bucket(i)
                rank = 0
                for k in range(self.bucket_start[b], self.bucket_start[b + 1]):
                    rank += int(self.unsorted[k] < i)
                self.filed[self.bucket_start[b] + rank] = i
