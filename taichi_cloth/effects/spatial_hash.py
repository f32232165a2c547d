"""A uniform grid of axis-aligned boxes hashed into buckets, rebuilt inside a kernel (no Python
per step): the broad phase of self-collision's patches (``effects/mesh_patches.py``).

``build(cell_size)`` files each of the ``count`` boxes (``lower``, ``upper`` [m], filled by the
caller) under every grid cell ⌊p / cell_size⌋ that the box overlaps, in buckets of a hash of the
cell (Teschner et al. 2003, "Optimized spatial hashing for collision detection of deformable
objects"): the entries per bucket counted, prefix-summed and filled, all in serial loops, so a
bucket lists its entries in box order and every loop over it sums in a fixed order
(bit-reproducible). Boxes of many cells each are filed under cells of twice the size, doubled
until the entries fit ``ENTRIES_PER_BOX`` per box. Cells sized like the boxes keep both the
entries per box and the boxes per cell small whatever the spread of box sizes (a grid of the
largest box's cell, queried over the 27 cells around an item, walked hundreds of items per query
where the mesh is fine).

Queries, by the caller, in a bucket's entries whose cell is the one asked for: the boxes that
overlap a box (its cells; a pair of boxes is counted in the first cell both span,
``first_common_cell``, so once).
"""

import taichi as ti

ENTRIES_PER_BOX = 8  # filed entries per box at most; more double the cell
BUCKETS_PER_BOX = 4  # hash buckets per box (rounded up to a power of two)
MAX_DOUBLINGS = 40  # a cloth that needs more (non-finite or exploded positions) files nothing


def power_of_two_at_least(count: int) -> int:
    """The smallest power of two ≥ count (≥ 1): a bucket count for ``hash_cell``."""
    return 1 << max(0, count - 1).bit_length()


@ti.func
def hash_cell(cell, bucket_count) -> ti.i32:
    """The bucket in [0, bucket_count) of a grid cell (three integer indices; bucket_count a
    power of two): the spatial hash of Teschner et al. (2003), the indices times three large
    primes combined by exclusive or, in 32-bit integers (wrapping), masked (a 64-bit modulo
    took a third of the self-intersection count)."""
    c = ti.cast(cell, ti.i32)
    code = (c[0] * 73856093) ^ (c[1] * 19349663) ^ (c[2] * 83492791)
    return code & (bucket_count - 1)


@ti.data_oriented
class BoxGrid:
    """``count`` boxes [m] (``lower``, ``upper``) filed by the grid cells they overlap (module
    docstring)."""

    def __init__(self, count: int, real):
        self.count = count
        self.capacity = max(1, ENTRIES_PER_BOX * count)
        self.bucket_count = power_of_two_at_least(BUCKETS_PER_BOX * count)
        self.lower = ti.Vector.field(3, real, count)
        self.upper = ti.Vector.field(3, real, count)
        self.cell_size = ti.field(real, ())  # m, of the last build
        self.filed = ti.field(ti.i32, ())  # whether the last build filed the boxes
        self.low_cell = ti.Vector.field(3, ti.i32, count)  # each box's first and last cells
        self.high_cell = ti.Vector.field(3, ti.i32, count)
        self.bucket_start = ti.field(ti.i32, self.bucket_count + 1)
        self.bucket_fill = ti.field(ti.i32, self.bucket_count)
        self.entry_box = ti.field(ti.i32, self.capacity)
        self.entry_cell = ti.Vector.field(3, ti.i32, self.capacity)

    @ti.func
    def cell_of(self, position):
        """The grid cell of a position [m]."""
        return ti.cast(ti.floor(position / self.cell_size[None]), ti.i32)

    @ti.func
    def bucket(self, cell) -> ti.i32:
        return hash_cell(cell, self.bucket_count)

    @ti.func
    def first_common_cell(self, i, j):
        """The lowest cell (per axis) that boxes i and j both overlap, if they share one."""
        return ti.max(self.low_cell[i], self.low_cell[j])

    @ti.func
    def overlap(self, i, j) -> ti.i32:
        """Whether boxes i and j overlap."""
        return int((self.lower[i] <= self.upper[j]).all()
                   and (self.lower[j] <= self.upper[i]).all())

    @ti.func
    def _entries(self, cell_size):
        """The entries [count] the boxes take on cells of ``cell_size`` (summed in float64, exact
        to 2⁵³, so that no integer overflows on exploded positions)."""
        entries = ti.f64(0.0)
        for i in range(self.count):
            span = ti.floor(self.upper[i] / cell_size) - ti.floor(self.lower[i] / cell_size) + 1
            entries += span[0] * span[1] * span[2]
        return entries

    @ti.func
    def build(self, cell_size):
        """File every box under each cell it overlaps, cells of ``cell_size`` [m] or a power of
        two times it (module docstring). Call it where its loops run serially (under a branch or
        a serial loop)."""
        size = cell_size
        doublings = 0
        while doublings < MAX_DOUBLINGS:
            if self._entries(size) <= self.capacity:  # (false for non-finite positions too)
                break
            size *= 2
            doublings += 1
        self.cell_size[None] = size
        self.filed[None] = int(doublings < MAX_DOUBLINGS)
        for b in range(self.bucket_count):
            self.bucket_fill[b] = 0
        if self.filed[None]:
            for i in range(self.count):
                low, high = self.cell_of(self.lower[i]), self.cell_of(self.upper[i])
                self.low_cell[i], self.high_cell[i] = low, high
                for cell in ti.grouped(ti.ndrange((low[0], high[0] + 1), (low[1], high[1] + 1),
                                                  (low[2], high[2] + 1))):
                    self.bucket_fill[self.bucket(cell)] += 1
        self.bucket_start[0] = 0
        for b in range(self.bucket_count):
            self.bucket_start[b + 1] = self.bucket_start[b] + self.bucket_fill[b]
            self.bucket_fill[b] = self.bucket_start[b]
        if self.bucket_start[self.bucket_count] > self.capacity:  # never written past the end
            self.filed[None] = 0
        if self.filed[None]:
            for i in range(self.count):
                low, high = self.low_cell[i], self.high_cell[i]
                for cell in ti.grouped(ti.ndrange((low[0], high[0] + 1), (low[1], high[1] + 1),
                                                  (low[2], high[2] + 1))):
                    bucket = self.bucket(cell)
                    slot = self.bucket_fill[bucket]
                    self.bucket_fill[bucket] = slot + 1
                    self.entry_box[slot] = i
                    self.entry_cell[slot] = cell
