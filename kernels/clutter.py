"""Clutter above the ground: bushes, grass and tree crowns as a second, "canopy" layer.

A real vehicle's scan is dominated by returns from above the ground. Over each cell ``(i, j)``
of the terrain grid (the square ``[i, i+1] x [j, j+1]`` in grid units, see ``heightfield``) the
canopy is one horizontal slab ``[bottom, top]`` (world metres; empty where ``bottom`` is NaN or
``bottom >= top``) with a ``density``: the probability that a ray returns per metre it travels
inside the slab (1: solid, always returns where it enters). A ray crossing ``L`` metres of slab
returns from it with probability ``1 - (1 - density)^L``, so the chance that a ray gets through
a slab does not depend on how its path is split between cells. Layers are
``(batch, H - 1, W - 1)`` arrays, one value per cell.

Items are drawn per sample (one thread per item slot, from the sample's seed, so sample ``b``
depends only on ``(seed, b)``) and stamped by one thread per cell:

- grass: square patches of ``grass_patch`` metres, each covered with probability
  ``grass_cover``, a layer from the ground up to a per-patch height in
  ``[grass_height_min, grass_height_max]`` above the cell centre's ground
- bush: a porous half-ellipsoid standing on the ground at its centre: radius ``r``, height
  ``h``; over a cell at distance ``d`` it spans from the ground up to ``h sqrt(1 - (d/r)^2)``
  above the ground at the bush's centre
- crown: an ellipsoid floating ``lift`` metres above the ground at the tree's foot (its bottom),
  ``depth`` metres deep: rays can pass under it and hit the ground

Where kinds overlap, the highest kind wins the cell (crown over bush over grass), so the gap
under a crown stays open; items of one kind that overlap merge into one slab (their union).
"""

import warp as wp

from .frames import sample_transform
from .ground_truth import subcell_point
from .heightfield import surface_height
from .rng import sample_seed, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator

STREAM_CLUTTER = wp.constant(0x3C6EF372)  # drawing the items of a sample
STREAM_CANOPY = wp.constant(0x5BE0CD19)  # a ray's draws against the canopy

GRASS = wp.constant(1)
BUSH = wp.constant(2)
CROWN = wp.constant(3)


@wp.struct
class ClutterSpec:
    """How to draw the clutter of one sample (metres; densities per metre, in [0, 1])."""

    bushes_min: int
    bushes_max: int
    bush_radius_min: float
    bush_radius_max: float
    bush_height_min: float
    bush_height_max: float
    bush_density: float
    trees_min: int
    trees_max: int
    crown_radius_min: float
    crown_radius_max: float
    crown_lift_min: float
    crown_lift_max: float
    crown_depth_min: float
    crown_depth_max: float
    crown_density: float
    grass_cover: float
    grass_patch: float
    grass_height_min: float
    grass_height_max: float
    grass_density: float
    region: float
    keep_out: float


@wp.struct
class ClutterItem:
    """One bush or crown: ``kind`` (0: none), centre (metres), radius, the world height of the
    ground at its centre, and the slab's bottom and top above that ground at the centre."""

    kind: int
    center: wp.vec2
    radius: float
    ground: float
    lift: float
    height: float


@wp.kernel
def sample_items(
    seeds: wp.array(dtype=int),
    first: int,
    spec: ClutterSpec,
    heights: wp.array3d(dtype=float),
    cell: float,
    items: wp.array2d(dtype=ClutterItem),
):
    """Draw item slot ``s`` of sample ``first + b``: slots ``[0, bushes_max)`` are bushes, the
    rest trees; each kind's count is drawn once per sample and slots beyond it stay empty.
    Centres are uniform in ``[-region, region]^2`` with the item ``keep_out`` metres clear of
    the sensor (32 tries)."""
    b, s = wp.tid()
    seed = seeds[0]
    out = ClutterItem()
    out.kind = 0
    kind = BUSH
    rank = s
    count_state = stream_state(seed, first + b, STREAM_CLUTTER, 0)
    count = wp.randi(count_state, spec.bushes_min, spec.bushes_max + 1)
    if s >= spec.bushes_max:
        kind = CROWN
        rank = s - spec.bushes_max
        count_state = stream_state(seed, first + b, STREAM_CLUTTER, 1)
        count = wp.randi(count_state, spec.trees_min, spec.trees_max + 1)
    if rank >= count:
        items[b, s] = out
        return
    state = stream_state(seed, first + b, STREAM_CLUTTER, 65536 + s)
    # (wp.randf advances ``state`` in place, so it is called here, not in a helper)
    radius = wp.randf(state, spec.bush_radius_min, spec.bush_radius_max)
    lift = float(0.0)
    height = wp.randf(state, spec.bush_height_min, spec.bush_height_max)
    if kind == CROWN:
        radius = wp.randf(state, spec.crown_radius_min, spec.crown_radius_max)
        lift = wp.randf(state, spec.crown_lift_min, spec.crown_lift_max)
        height = lift + wp.randf(state, spec.crown_depth_min, spec.crown_depth_max)
    for _attempt in range(32):
        center = wp.vec2(wp.randf(state, -spec.region, spec.region), wp.randf(state, -spec.region, spec.region))
        if wp.length(center) - radius >= spec.keep_out:
            H = heights.shape[1]
            W = heights.shape[2]
            out.kind = kind
            out.center = center
            out.radius = radius
            out.ground = surface_height(heights, b, center[0] / cell + 0.5 * float(H - 1), center[1] / cell + 0.5 * float(W - 1))
            out.lift = lift
            out.height = height
            break
    items[b, s] = out


@wp.func
def grass_height(seed: int, b: int, spec: ClutterSpec, x: float, y: float) -> float:
    """Height of the grass over world point (x, y), 0 where its patch is bare."""
    if spec.grass_cover <= 0.0:
        return 0.0
    pi = int(wp.floor(x / spec.grass_patch))
    pj = int(wp.floor(y / spec.grass_patch))
    state = wp.rand_init(sample_seed(seed, b) ^ STREAM_CLUTTER, pi * 7919 + pj * 104729)
    covered = wp.randf(state) < spec.grass_cover
    h = wp.randf(state, spec.grass_height_min, spec.grass_height_max)
    if covered:
        return h
    return 0.0


@wp.func
def cell_ground(heights: wp.array3d(dtype=float), b: int, i: int, j: int) -> wp.vec2:
    """Lowest corner and centre height of cell ``(i, j)``'s ground."""
    lo = wp.min(wp.min(heights[b, i, j], heights[b, i + 1, j]), wp.min(heights[b, i, j + 1], heights[b, i + 1, j + 1]))
    return wp.vec2(lo, surface_height(heights, b, float(i) + 0.5, float(j) + 0.5))


@wp.kernel
def stamp_canopy(
    seeds: wp.array(dtype=int),
    first: int,
    spec: ClutterSpec,
    items: wp.array2d(dtype=ClutterItem),
    heights: wp.array3d(dtype=float),
    cell: float,
    bottom: wp.array3d(dtype=float),
    top: wp.array3d(dtype=float),
    density: wp.array3d(dtype=float),
):
    """The canopy slab of cell ``(i, j)`` of sample ``b`` (numbered ``first + b``): the highest
    kind over the cell's centre wins, items of that kind merge (lowest bottom, highest top)."""
    b, i, j = wp.tid()
    seed = seeds[0]
    H = heights.shape[1]
    W = heights.shape[2]
    x = (float(i) + 0.5 - 0.5 * float(H - 1)) * cell
    y = (float(j) + 0.5 - 0.5 * float(W - 1)) * cell
    ground = cell_ground(heights, b, i, j)
    best = int(0)
    lo = float(0.0)
    hi = float(0.0)
    for s in range(items.shape[1]):
        it = items[b, s]
        if it.kind == 0:
            continue
        d = wp.length(wp.vec2(x, y) - it.center) / it.radius
        if d >= 1.0:
            continue
        k = wp.sqrt(1.0 - d * d)
        if it.kind == BUSH:
            item_lo = ground[0]
            item_hi = it.ground + it.height * k
        else:
            mid = it.ground + 0.5 * (it.lift + it.height)
            half = 0.5 * (it.height - it.lift) * k
            item_lo = mid - half
            item_hi = mid + half
        if item_hi <= item_lo:
            continue
        if it.kind > best:
            best = it.kind
            lo = item_lo
            hi = item_hi
        elif it.kind == best:
            lo = wp.min(lo, item_lo)
            hi = wp.max(hi, item_hi)
    rho = float(0.0)
    if best == BUSH:
        rho = spec.bush_density
    elif best == CROWN:
        rho = spec.crown_density
    else:
        g = grass_height(seed, first + b, spec, x, y)
        if g > 0.0:
            best = GRASS
            lo = ground[0]
            hi = ground[1] + g
            rho = spec.grass_density
    if best == 0 or not (hi > lo):
        bottom[b, i, j] = wp.nan
        top[b, i, j] = wp.nan
        density[b, i, j] = 0.0
        return
    bottom[b, i, j] = lo
    top[b, i, j] = hi
    density[b, i, j] = rho


@wp.kernel
def raise_tiles(
    top: wp.array3d(dtype=float),
    density: wp.array3d(dtype=float),
    tile: int,
    tile_max: wp.array3d(dtype=float),
    terrain_max: wp.array(dtype=float),
):
    """Raise each max-height tile (and each terrain's max) to the canopy tops over its cells,
    so a ray skipping a tile never skips a canopy it could meet. Cells of density 0 (which no
    ray can see) are left out: they leave the walk exactly as it is without clutter."""
    b, i, j = wp.tid()
    t = top[b, i, j]
    if density[b, i, j] > 0.0 and t == t:
        wp.atomic_max(tile_max, b, i // tile, j // tile, t)
        wp.atomic_max(terrain_max, b, t)


@wp.kernel
def cell_mean_visible(
    heights: wp.array3d(dtype=float),
    top: wp.array3d(dtype=float),
    density: wp.array3d(dtype=float),
    cell: float,
    sensor_z: wp.array(dtype=float),
    map_cell: float,
    samples: int,
    seeds: wp.array(dtype=int),
    augment: int,
    target: wp.array4d(dtype=float),
):
    """The visible surface per map cell: at each of the ``samples^2`` sub-cell points (as in
    ``ground_truth.cell_mean_heights``) the higher of the ground and the canopy top over the
    terrain cell there (cells of density 0 are empty), averaged, in the sensor frame."""
    b, p, q = wp.tid()
    seed = seeds[0]
    H = heights.shape[1]
    W = heights.shape[2]
    S = target.shape[2]
    half = 0.5 * float(S - 1)
    d = sample_transform(seed, b, augment)
    step = 1.0 / float(samples)
    acc = float(0.0)
    for si in range(samples):
        for sj in range(samples):
            uv = subcell_point(p, q, si, sj, half, step, map_cell, d, cell, H, W)
            u = uv[0]
            v = uv[1]
            z = surface_height(heights, b, u, v)
            i = wp.clamp(int(wp.floor(u)), 0, H - 2)
            j = wp.clamp(int(wp.floor(v)), 0, W - 2)
            t = top[b, i, j]
            if density[b, i, j] > 0.0 and t == t:
                z = wp.max(z, t)
            acc += z
    target[b, 0, p, q] = acc * step * step - sensor_z[b]
