"""Where the rays are cast: exact LIDAR ray casting against heightfields, no BVH.

Every sample of the stream has a fresh terrain, so a method that must first build an
acceleration structure (a BVH for ``wp.mesh_query_ray`` or Embree) pays that build on every
scan. A heightfield is already its own acceleration structure: each ray walks the cells under
its x-y projection in order (a 2-D DDA, Amanatides & Woo) and intersects exactly the two
triangles of each cell it crosses (the same triangles a mesh of the heightfield holds), so the
first surface met is found, obstacle sides and the far walls of pits included. Tiles of
``tile x tile`` cells with their max height let a ray skip every tile it passes above without
touching its cells; a ray heading up above the highest point of its terrain stops at once.

Ray ``r`` of sample ``b`` starts at the sensor, above the heightfield's centre, and leaves
with unit direction ``directions[r]`` (sensor frame = world axes). The hit is written in the
sensor frame; rays with no return (no surface within range, outside ``[min_range, max_range]``
after noise, or dropped) are written as NaN.
"""

import warp as wp

from .frames import dihedral_apply, sample_transform
from .heightfield import cell_plane_height
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
    heights: wp.array3d(dtype=float),
    b: int,
    i: int,
    j: int,
    a0: float,
    c0: float,
    z0: float,
    du: float,
    dv: float,
    dz: float,
    s0: float,
    s1: float,
) -> float:
    """First t in [s0, s1] where the ray meets the one triangle of cell (i, j) it is over.

    Over a piece of the ray that stays on one side of the cell's diagonal the surface is one
    plane, so the ray's height above it is linear in t and the crossing is exact.
    """
    tm = 0.5 * (s0 + s1)
    upper = a0 + du * tm >= c0 + dv * tm
    f0 = z0 + dz * s0 - cell_plane_height(heights, b, i, j, a0 + du * s0, c0 + dv * s0, upper)
    if f0 < 0.0:
        return s0
    f1 = z0 + dz * s1 - cell_plane_height(heights, b, i, j, a0 + du * s1, c0 + dv * s1, upper)
    if f1 < 0.0:
        return s0 + (s1 - s0) * f0 / (f0 - f1)
    return NO_HIT


@wp.func
def cell_hit(
    heights: wp.array3d(dtype=float),
    b: int,
    i: int,
    j: int,
    u0: float,
    v0: float,
    z0: float,
    du: float,
    dv: float,
    dz: float,
    s0: float,
    s1: float,
) -> float:
    """First t in [s0, s1] where the ray meets cell (i, j)'s two triangles, or NO_HIT."""
    a0 = u0 - float(i)
    c0 = v0 - float(j)
    split = s1
    if du != dv:
        t_diagonal = (c0 - a0) / (du - dv)
        if t_diagonal > s0 and t_diagonal < s1:
            split = t_diagonal
    t = triangle_hit(heights, b, i, j, a0, c0, z0, du, dv, dz, s0, split)
    if t == NO_HIT and split < s1:
        t = triangle_hit(heights, b, i, j, a0, c0, z0, du, dv, dz, split, s1)
    return t


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
    nudge: float,
) -> float:
    """Distance along the ray to the first surface of heightfield ``b`` before ``t_end``.

    Grid coordinates: the ray is ``(u0 + du t, v0 + dv t, z0 + dz t)`` with t in metres.
    ``nudge`` (a small t) picks the cell the ray is entering at a cell boundary; the
    intersection itself is always taken from the boundary, so nothing is skipped.
    """
    H = heights.shape[1]
    W = heights.shape[2]
    t = float(0.0)
    open_ti = int(-1)
    open_tj = int(-1)
    while t < t_end:
        z = z0 + dz * t
        if dz >= 0.0 and z > top:
            return NO_HIT
        tn = t + nudge
        i = int(wp.floor(u0 + du * tn))
        j = int(wp.floor(v0 + dv * tn))
        if i < 0 or i > H - 2 or j < 0 or j > W - 2:
            return NO_HIT
        ti = i // tile
        tj = j // tile
        if ti != open_ti or tj != open_tj:
            # entering a tile: skip it whole if the ray passes above its highest vertex
            hi_u = float(wp.min(ti * tile + tile, H - 1))
            hi_v = float(wp.min(tj * tile + tile, W - 1))
            t_tile = wp.min(
                wp.min(slab_exit(u0, du, float(ti * tile), hi_u), slab_exit(v0, dv, float(tj * tile), hi_v)),
                t_end,
            )
            t_tile = wp.max(t_tile, tn)
            if wp.min(z, z0 + dz * t_tile) > tile_max[b, ti, tj]:
                t = t_tile
                continue
            open_ti = ti
            open_tj = tj
        t_cell = wp.min(
            wp.min(slab_exit(u0, du, float(i), float(i + 1)), slab_exit(v0, dv, float(j), float(j + 1))),
            t_end,
        )
        t_cell = wp.max(t_cell, tn)
        hit = cell_hit(heights, b, i, j, u0, v0, z0, du, dv, dz, t, t_cell)
        if hit != NO_HIT:
            if hit > t_end:
                return NO_HIT
            return hit
        t = t_cell
    return NO_HIT


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
    lo_u = 0.0
    hi_u = float(H - 1)
    lo_v = 0.0
    hi_v = float(W - 1)
    if reach > 0.0:
        lo_u = wp.max(lo_u, u0 - reach / cell)
        hi_u = wp.min(hi_u, u0 + reach / cell)
        lo_v = wp.max(lo_v, v0 - reach / cell)
        hi_v = wp.min(hi_v, v0 + reach / cell)
    t_end = wp.min(max_range, wp.min(slab_exit(u0, du, lo_u, hi_u), slab_exit(v0, dv, lo_v, hi_v)))
    t = trace_heightfield(
        heights, tile_max, terrain_max[b], tile, b, u0, v0, sensor_z[b], du, dv, d[2], t_end, 1.0e-3 * cell
    )
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
