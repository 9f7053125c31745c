"""Ground projection: LIDAR points binned into elevation maps, and image noise.

Point (x, y, z) (sensor frame) falls in map cell ``(round(x / map_cell + (S-1)/2),
round(y / map_cell + (S-1)/2))``; a cell's height is the mean z of its points and its mask is 1
when it got at least one. Non-finite points and points outside the map are ignored.
"""

import warp as wp

from .rng import STREAM_IMAGE_NOISE, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator


@wp.func
def map_cell_of(p: wp.vec3, map_cell: float, S: int) -> wp.vec2i:
    """The map cell ``(i, j)`` point ``p`` falls in, or ``(-1, -1)`` for a non-finite point or
    one outside the ``S x S`` map."""
    if not (wp.isfinite(p[0]) and wp.isfinite(p[1]) and wp.isfinite(p[2])):
        return wp.vec2i(-1, -1)
    half = 0.5 * float(S - 1)
    fi = wp.floor(p[0] / map_cell + half + 0.5)
    fj = wp.floor(p[1] / map_cell + half + 0.5)
    # compare as floats so that huge coordinates cannot overflow an int
    if fi < 0.0 or fj < 0.0 or fi >= float(S) or fj >= float(S):
        return wp.vec2i(-1, -1)
    return wp.vec2i(int(fi), int(fj))


@wp.kernel
def bin_points(
    points: wp.array2d(dtype=wp.vec3),
    map_cell: float,
    height_sum: wp.array3d(dtype=wp.float64),
    count: wp.array3d(dtype=int),
    height_max: wp.array3d(dtype=float),
):
    b, n = wp.tid()
    p = points[b, n]
    cell = map_cell_of(p, map_cell, height_sum.shape[1])
    if cell[0] < 0:
        return
    i = cell[0]
    j = cell[1]
    wp.atomic_add(height_sum, b, i, j, wp.float64(p[2]))  # float64: no overflow, no drift
    wp.atomic_add(count, b, i, j, 1)
    wp.atomic_max(height_max, b, i, j, p[2])


@wp.kernel
def finish_maps(
    height_sum: wp.array3d(dtype=wp.float64),
    count: wp.array3d(dtype=int),
    height_max: wp.array3d(dtype=float),
    fill: float,
    height: wp.array4d(dtype=float),
    top: wp.array4d(dtype=float),
    mask: wp.array4d(dtype=float),
):
    """Mean and max height per observed cell; ``fill`` and mask 0 where nothing landed."""
    b, i, j = wp.tid()
    n = count[b, i, j]
    if n > 0:
        height[b, 0, i, j] = float(height_sum[b, i, j] / wp.float64(n))
        top[b, 0, i, j] = height_max[b, i, j]
        mask[b, 0, i, j] = 1.0
    else:
        height[b, 0, i, j] = fill
        top[b, 0, i, j] = fill
        mask[b, 0, i, j] = 0.0


@wp.kernel
def bin_offsets(
    points: wp.array2d(dtype=wp.vec3),
    map_cell: float,
    offset_sum: wp.array4d(dtype=wp.float64),
    count: wp.array3d(dtype=int),
):
    """Per cell, the sum of its points' horizontal offsets from the cell's centre (``offset_sum``
    ``(B, 2, S, S)``: x then y) and their count; the cells of ``bin_points`` (``map_cell_of``)."""
    b, n = wp.tid()
    p = points[b, n]
    S = count.shape[1]
    cell = map_cell_of(p, map_cell, S)
    if cell[0] < 0:
        return
    i = cell[0]
    j = cell[1]
    half = 0.5 * float(S - 1)
    # the offset in float64: a point far from the sensor keeps its centimetres
    wp.atomic_add(offset_sum, b, 0, i, j, wp.float64(p[0]) - wp.float64(float(i) - half) * wp.float64(map_cell))
    wp.atomic_add(offset_sum, b, 1, i, j, wp.float64(p[1]) - wp.float64(float(j) - half) * wp.float64(map_cell))
    wp.atomic_add(count, b, i, j, 1)


@wp.kernel
def finish_offsets(offset_sum: wp.array4d(dtype=wp.float64), count: wp.array3d(dtype=int), offset: wp.array4d(dtype=float)):
    """Mean offset per observed cell, 0 where nothing landed."""
    b, c, i, j = wp.tid()
    n = count[b, i, j]
    if n > 0:
        offset[b, c, i, j] = float(offset_sum[b, c, i, j] / wp.float64(n))
    else:
        offset[b, c, i, j] = 0.0


@wp.kernel
def add_image_noise(
    seeds: wp.array(dtype=int),
    noise: float,
    height_range: wp.array(dtype=float),
    mask: wp.array4d(dtype=float),
    height: wp.array4d(dtype=float),
):
    """The paper's "x% noise": Gaussian noise of ``noise`` times the sample's height range,
    added to observed cells only."""
    b, i, j = wp.tid()
    seed = seeds[0]
    if mask[b, 0, i, j] > 0.0:
        S = height.shape[3]
        state = stream_state(seed, b, STREAM_IMAGE_NOISE, i * S + j)
        height[b, 0, i, j] = height[b, 0, i, j] + noise * height_range[b] * wp.randn(state)


@wp.kernel
def row_extremes(image: wp.array4d(dtype=float), row_lo: wp.array2d(dtype=float), row_hi: wp.array2d(dtype=float)):
    """Lowest and highest value of each image row: one thread per (sample, row), no atomics
    (the first half of ``height_range``'s reduction)."""
    b, i = wp.tid()
    lo = image[b, 0, i, 0]
    hi = lo
    for j in range(1, image.shape[3]):
        v = image[b, 0, i, j]
        lo = wp.min(lo, v)
        hi = wp.max(hi, v)
    row_lo[b, i] = lo
    row_hi[b, i] = hi


@wp.kernel
def height_range(row_lo: wp.array2d(dtype=float), row_hi: wp.array2d(dtype=float), span: wp.array(dtype=float)):
    """Each sample's height range (highest minus lowest value) from its rows' extremes."""
    b = wp.tid()
    lo = row_lo[b, 0]
    hi = row_hi[b, 0]
    for i in range(1, row_lo.shape[1]):
        lo = wp.min(lo, row_lo[b, i])
        hi = wp.max(hi, row_hi[b, i])
    span[b] = hi - lo
