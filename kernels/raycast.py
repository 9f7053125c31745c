"""Where the rays are cast: exact LIDAR ray casting against heightfields, no BVH.

Every sample of the stream has a fresh terrain, so a method that must first build an
acceleration structure (a BVH for ``wp.mesh_query_ray`` or Embree) pays that build on every
scan. A heightfield is already its own acceleration structure: each ray walks the cells under
its x-y projection in order (a 2-D DDA, Amanatides & Woo) and intersects exactly the two
triangles of each cell it crosses (the same triangles a mesh of the heightfield holds), so the
first surface met is found, obstacle sides and the far walls of pits included. Tiles of
``tile x tile`` cells with their max height let a ray skip every tile it passes above without
touching its cells; a ray heading up above the highest point of its terrain stops at once.

A spinning LIDAR's rays come in azimuth columns, and the rays of a column share one vertical
plane, so ``cast_columns`` walks each column once for all its rings (lowest first: in that
plane a lower ray never meets the terrain beyond a higher one). ``cast_rays`` walks each ray on
its own; it serves rings that point straight up or down and checks the column walk in tests.

Ray ``r`` of sample ``b`` starts at the sensor, above the heightfield's centre, and leaves
with unit direction ``directions[r]`` (sensor frame = world axes). The hit is written in the
sensor frame; rays with no return (no surface within range, outside ``[min_range, max_range]``
after noise, or dropped) are written as NaN.
"""

import warp as wp

from .frames import dihedral_apply, sample_transform
from .heightfield import plane_height
from .rng import STREAM_RAYS, stream_state

NO_HIT = wp.constant(-1.0)
FAR = wp.constant(1.0e30)


@wp.func
def slab_exit(origin: float, direction: float, lo: float, hi: float) -> float:
    """Ray parameter at which ``origin + direction * t`` leaves ``[lo, hi]``."""
    if direction > 0.0:
        return (hi - origin) / direction
    if direction < 0.0:
        return (lo - origin) / direction
    return FAR


@wp.func
def triangle_hit(
    h00: float,
    h10: float,
    h01: float,
    h11: float,
    a0: float,
    c0: float,
    z0: float,
    du: float,
    dv: float,
    dz: float,
    s0: float,
    s1: float,
) -> float:
    """First t in [s0, s1] where the ray meets the one triangle of the cell it is over.

    Over a piece of the ray that stays on one side of the cell's diagonal the surface is one
    plane, so the ray's height above it is linear in t and the crossing is exact.
    """
    tm = 0.5 * (s0 + s1)
    upper = a0 + du * tm >= c0 + dv * tm
    f0 = z0 + dz * s0 - plane_height(h00, h10, h01, h11, a0 + du * s0, c0 + dv * s0, upper)
    if f0 < 0.0:
        return s0
    f1 = z0 + dz * s1 - plane_height(h00, h10, h01, h11, a0 + du * s1, c0 + dv * s1, upper)
    if f1 < 0.0:
        return s0 + (s1 - s0) * f0 / (f0 - f1)
    return NO_HIT


@wp.func
def cell_hit(
    h00: float,
    h10: float,
    h01: float,
    h11: float,
    a0: float,
    c0: float,
    z0: float,
    du: float,
    dv: float,
    dz: float,
    s0: float,
    s1: float,
) -> float:
    """First t in [s0, s1] where the ray meets a cell's two triangles, or NO_HIT.

    ``(a0, c0)`` is the ray origin relative to the cell's (i, j) corner, in cells.
    """
    split = s1
    if du != dv:
        t_diagonal = (c0 - a0) / (du - dv)
        if t_diagonal > s0 and t_diagonal < s1:
            split = t_diagonal
    t = triangle_hit(h00, h10, h01, h11, a0, c0, z0, du, dv, dz, s0, split)
    if t == NO_HIT and split < s1:
        t = triangle_hit(h00, h10, h01, h11, a0, c0, z0, du, dv, dz, split, s1)
    return t


@wp.func
def next_boundary(origin: float, inv_direction: float, index: int, step: int) -> float:
    """Ray parameter of the cell boundary the ray crosses next along one axis."""
    if step > 0:
        return (float(index + 1) - origin) * inv_direction
    if step < 0:
        return (float(index) - origin) * inv_direction
    return FAR


@wp.func
def cell_index(u: float, step: int) -> int:
    """The cell a ray moving by ``step`` along an axis is in at coordinate ``u``: on a boundary,
    the one it is entering."""
    i = int(wp.floor(u))
    if step < 0 and float(i) == u:
        i -= 1
    return i


@wp.func
def forward(current: int, candidate: int, step: int) -> int:
    """``candidate``, unless it lies behind ``current`` for a ray moving by ``step``."""
    if step > 0:
        return wp.max(current, candidate)
    if step < 0:
        return wp.min(current, candidate)
    return current


@wp.func
def axis_step(direction: float) -> int:
    """+1, -1 or 0: how a ray moving by ``direction`` steps through cells along one axis."""
    if direction > 0.0:
        return 1
    if direction < 0.0:
        return -1
    return 0


@wp.func
def inverse(direction: float, step: int) -> float:
    """``1 / direction``, or 0 for an axis the ray does not move along."""
    if step == 0:
        return 0.0
    return 1.0 / direction


@wp.func
def tile_exits(u0: float, v0: float, inv_du: float, inv_dv: float, ti: int, tj: int, tile: int, step_i: int, step_j: int) -> wp.vec2:
    """Ray parameters at which the ray leaves tile ``(ti, tj)`` along each axis."""
    return wp.vec2(
        next_boundary(u0, inv_du, ti * tile + wp.max(step_i, 0) * (tile - 1), step_i),
        next_boundary(v0, inv_dv, tj * tile + wp.max(step_j, 0) * (tile - 1), step_j),
    )


@wp.func
def cell_beyond_tile(
    exits: wp.vec2, t: float, i: int, j: int, ti: int, tj: int, tile: int, u0: float, v0: float, du: float, dv: float, step_i: int, step_j: int
) -> wp.vec2i:
    """The cell a ray enters when it leaves tile ``(ti, tj)`` at ``t``: the exit axis moves into
    the next tile; the other follows the ray but never backwards (a ray through a tile corner
    must not bounce between two tiles)."""
    if exits[0] <= exits[1]:
        return wp.vec2i(ti * tile + wp.max(step_i, 0) * tile - wp.max(-step_i, 0), forward(j, cell_index(v0 + dv * t, step_j), step_j))
    return wp.vec2i(forward(i, cell_index(u0 + du * t, step_i), step_i), tj * tile + wp.max(step_j, 0) * tile - wp.max(-step_j, 0))


@wp.func
def corner_heights(heights: wp.array3d(dtype=float), b: int, i: int, j: int) -> wp.vec4:
    """Heights of cell ``(i, j)``'s corners (i, j), (i+1, j), (i, j+1), (i+1, j+1)."""
    return wp.vec4(heights[b, i, j], heights[b, i + 1, j], heights[b, i, j + 1], heights[b, i + 1, j + 1])


@wp.func
def trace_heightfield(
    heights: wp.array3d(dtype=float),
    tile_max: wp.array3d(dtype=float),
    top: float,
    tile: int,
    b: int,
    u0: float,
    v0: float,
    z0: float,
    du: float,
    dv: float,
    dz: float,
    t_end: float,
) -> float:
    """Distance along the ray to the first surface of heightfield ``b`` before ``t_end``.

    Grid coordinates: the ray is ``(u0 + du t, v0 + dv t, z0 + dz t)`` with t in metres. The
    walk is an incremental DDA: each step moves to the neighbouring cell whose boundary the ray
    crosses first, and each boundary's t is computed from its integer coordinate (no drift).
    A cell whose four corners all lie below the ray over its segment is passed without the exact
    test; a tile the ray passes above is skipped whole, the walk resuming in the cell beyond the
    tile boundary it leaves through. Cells are picked by the direction of travel, so a ray on a
    boundary is in the cell it enters and never stalls.
    """
    H = heights.shape[1]
    W = heights.shape[2]
    step_i = axis_step(du)
    step_j = axis_step(dv)
    inv_du = inverse(du, step_i)
    inv_dv = inverse(dv, step_j)
    t = float(0.0)
    i = cell_index(u0, step_i)
    j = cell_index(v0, step_j)
    open_ti = int(-1)
    open_tj = int(-1)
    while t < t_end:
        z = z0 + dz * t
        if dz >= 0.0 and z > top:
            return NO_HIT
        if i < 0 or i > H - 2 or j < 0 or j > W - 2:
            return NO_HIT
        ti = i // tile
        tj = j // tile
        if ti != open_ti or tj != open_tj:
            # entering a tile: skip it whole if the ray passes above its highest vertex
            exits = tile_exits(u0, v0, inv_du, inv_dv, ti, tj, tile, step_i, step_j)
            t_tile = wp.min(wp.min(exits[0], exits[1]), t_end)
            if wp.min(z, z0 + dz * t_tile) > tile_max[b, ti, tj]:
                if t_tile >= t_end:
                    return NO_HIT
                t = wp.max(t, t_tile)
                entered = cell_beyond_tile(exits, t, i, j, ti, tj, tile, u0, v0, du, dv, step_i, step_j)
                i = entered[0]
                j = entered[1]
                continue
            open_ti = ti
            open_tj = tj
        t_u = next_boundary(u0, inv_du, i, step_i)
        t_v = next_boundary(v0, inv_dv, j, step_j)
        t_cell = wp.max(wp.min(wp.min(t_u, t_v), t_end), t)
        corner = corner_heights(heights, b, i, j)
        if wp.min(z, z0 + dz * t_cell) <= wp.max(wp.max(corner[0], corner[1]), wp.max(corner[2], corner[3])):
            hit = cell_hit(corner[0], corner[1], corner[2], corner[3], u0 - float(i), v0 - float(j), z0, du, dv, dz, t, t_cell)
            if hit != NO_HIT:
                return hit
        if t_u <= t_v:
            i += step_i
        else:
            j += step_j
        t = t_cell
    return NO_HIT


@wp.func
def write_return(
    points: wp.array2d(dtype=wp.vec3),
    b: int,
    r: int,
    d: wp.vec3,
    t: float,
    min_range: float,
    max_range: float,
    range_noise_std: float,
    dropout: float,
    seed: int,
    augment: int,
):
    """Ray ``r`` of scan ``b`` met the surface at distance ``t`` (or NO_HIT): write the return
    the sensor reports (range noise, dropout, range gate; sample flip/rotation) or NaN."""
    nan = wp.nan
    out = wp.vec3(nan, nan, nan)
    if t != NO_HIT:
        state = stream_state(seed, b, STREAM_RAYS, r)
        measured = t
        if range_noise_std > 0.0:
            measured = t + range_noise_std * wp.randn(state)
        kept = wp.randf(state) >= dropout
        if kept and measured >= min_range and measured <= max_range:
            p = d * measured
            xy = dihedral_apply(sample_transform(seed, b, augment), wp.vec2(p[0], p[1]))
            out = wp.vec3(xy[0], xy[1], p[2])
    points[b, r] = out


@wp.func
def reach_box(H: int, W: int, cell: float, reach: float) -> wp.vec4:
    """Grid-coordinate bounds ``(lo_u, hi_u, lo_v, hi_v)`` a ray may travel in."""
    u0 = 0.5 * float(H - 1)
    v0 = 0.5 * float(W - 1)
    box = wp.vec4(0.0, float(H - 1), 0.0, float(W - 1))
    if reach > 0.0:
        box = wp.vec4(
            wp.max(box[0], u0 - reach / cell), wp.min(box[1], u0 + reach / cell), wp.max(box[2], v0 - reach / cell), wp.min(box[3], v0 + reach / cell)
        )
    return box


@wp.kernel
def cast_rays(
    heights: wp.array3d(dtype=float),
    tile_max: wp.array3d(dtype=float),
    terrain_max: wp.array(dtype=float),
    sensor_z: wp.array(dtype=float),
    tile: int,
    cell: float,
    directions: wp.array(dtype=wp.vec3),
    min_range: float,
    max_range: float,
    range_noise_std: float,
    dropout: float,
    reach: float,
    seed: int,
    augment: int,
    points: wp.array2d(dtype=wp.vec3),
):
    """One thread per (scan, ray): every ray of every scan in the batch in one launch.

    Rays stop where they leave the square ``+-reach`` metres around the sensor (``reach <= 0``:
    the whole heightfield), so a caller that only bins points into a map casts no further.
    """
    b, r = wp.tid()
    H = heights.shape[1]
    W = heights.shape[2]
    d = directions[r]
    u0 = 0.5 * float(H - 1)
    v0 = 0.5 * float(W - 1)
    du = d[0] / cell
    dv = d[1] / cell
    box = reach_box(H, W, cell, reach)
    t_end = wp.min(max_range, wp.min(slab_exit(u0, du, box[0], box[1]), slab_exit(v0, dv, box[2], box[3])))
    t = trace_heightfield(heights, tile_max, terrain_max[b], tile, b, u0, v0, sensor_z[b], du, dv, d[2], t_end)
    write_return(points, b, r, d, t, min_range, max_range, range_noise_std, dropout, seed, augment)


@wp.kernel
def cast_columns(
    heights: wp.array3d(dtype=float),
    tile_max: wp.array3d(dtype=float),
    terrain_max: wp.array(dtype=float),
    sensor_z: wp.array(dtype=float),
    tile: int,
    cell: float,
    directions: wp.array(dtype=wp.vec3),
    rings: int,
    first_column: int,
    column_step: int,
    min_range: float,
    max_range: float,
    range_noise_std: float,
    dropout: float,
    reach: float,
    seed: int,
    augment: int,
    points: wp.array2d(dtype=wp.vec3),
):
    """One thread per (scan, azimuth column): all rings of a column in one walk.

    The rays of a column lie in one vertical plane through the sensor, and in that plane a
    lower ray meets the terrain no farther than a higher one (where the higher ray meets the
    surface, the lower one is already below it). So a single DDA walk outward along the
    column's azimuth serves every ring: the lowest ring not yet hit is tested cell by cell;
    when it hits, the next ring is tested from the same cell on. A tile (or cell) the lowest
    ring passes above is passed by every higher ring too. The walk is parameterised by
    horizontal distance ``s``; ring ``k`` is at height ``z0 + s tan(e_k)`` and range ``s / cos(e_k)``.
    Needs every ray off the vertical (``cos(e) > 0``) and rays ordered ring-major, lowest ring
    first (``LidarConfig.ray_directions``); hits equal ``cast_rays``' to float rounding. Thread
    ``c`` walks column ``first_column + c * column_step``, so processes can share a scan's columns.
    """
    b, c = wp.tid()
    c = first_column + c * column_step
    H = heights.shape[1]
    W = heights.shape[2]
    columns = directions.shape[0] // rings
    d0 = directions[c]
    h0 = wp.sqrt(d0[0] * d0[0] + d0[1] * d0[1])
    du = d0[0] / (h0 * cell)  # grid cells per metre of horizontal travel
    dv = d0[1] / (h0 * cell)
    u0 = 0.5 * float(H - 1)
    v0 = 0.5 * float(W - 1)
    z0 = sensor_z[b]
    top = terrain_max[b]
    box = reach_box(H, W, cell, reach)
    s_box = wp.min(slab_exit(u0, du, box[0], box[1]), slab_exit(v0, dv, box[2], box[3]))
    step_i = axis_step(du)
    step_j = axis_step(dv)
    inv_du = inverse(du, step_i)
    inv_dv = inverse(dv, step_j)
    s = float(0.0)
    i = cell_index(u0, step_i)
    j = cell_index(v0, step_j)
    open_ti = int(-1)
    open_tj = int(-1)
    k = int(0)
    r = c
    d = d0
    h = h0
    slope = d0[2] / h0
    s_end = wp.min(s_box, max_range * h0)
    while k < rings:
        z = z0 + slope * s
        t_hit = NO_HIT
        ring_done = bool(False)
        if s >= s_end or (slope >= 0.0 and z > top) or i < 0 or i > H - 2 or j < 0 or j > W - 2:
            ring_done = True  # this ring has left its range, risen above everything, or left the grid
        else:
            ti = i // tile
            tj = j // tile
            skipped = bool(False)
            if ti != open_ti or tj != open_tj:
                exits = tile_exits(u0, v0, inv_du, inv_dv, ti, tj, tile, step_i, step_j)
                s_tile = wp.min(wp.min(exits[0], exits[1]), s_end)
                if wp.min(z, z0 + slope * s_tile) > tile_max[b, ti, tj]:
                    skipped = True
                    if s_tile >= s_end:
                        ring_done = True
                    else:
                        s = wp.max(s, s_tile)
                        entered = cell_beyond_tile(exits, s, i, j, ti, tj, tile, u0, v0, du, dv, step_i, step_j)
                        i = entered[0]
                        j = entered[1]
                else:
                    open_ti = ti
                    open_tj = tj
            if not skipped:
                t_u = next_boundary(u0, inv_du, i, step_i)
                t_v = next_boundary(v0, inv_dv, j, step_j)
                s_cell = wp.max(wp.min(wp.min(t_u, t_v), s_end), s)
                corner = corner_heights(heights, b, i, j)
                if wp.min(z, z0 + slope * s_cell) <= wp.max(wp.max(corner[0], corner[1]), wp.max(corner[2], corner[3])):
                    hit = cell_hit(corner[0], corner[1], corner[2], corner[3], u0 - float(i), v0 - float(j), z0, du, dv, slope, s, s_cell)
                    if hit != NO_HIT:
                        t_hit = hit / h
                        ring_done = True
                if not ring_done:
                    if s_cell >= s_end:
                        ring_done = True  # the ring's range ends inside this cell
                    else:
                        if t_u <= t_v:
                            i += step_i
                        else:
                            j += step_j
                        s = s_cell
        if ring_done:
            write_return(points, b, r, d, t_hit, min_range, max_range, range_noise_std, dropout, seed, augment)
            k += 1
            if k < rings:
                r = k * columns + c
                d = directions[r]
                h = wp.sqrt(d[0] * d[0] + d[1] * d[1])
                slope = d[2] / h
                s_end = wp.min(s_box, max_range * h)
                open_ti = -1  # the new ring re-checks the tile it is in
                open_tj = -1
