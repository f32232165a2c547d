"""The spatial hash of grid cells (Teschner et al. 2003, "Optimized spatial hashing for collision
detection of deformable objects"): the buckets of the self-intersection count's grid
(``physics/intersections.py``).
"""

import taichi as ti


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
