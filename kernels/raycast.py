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
plane a lower ray never meets the terrain beyond a higher one). The walk exists once, as
``walk``: ``cast_columns`` runs it per column, moving on to the next ring where a ring's
walk is over; ``cast_rays`` runs it per ray, for rings that point straight up or down (no
horizontal direction to walk a column by) and as the column walk's check in tests.

Clutter (``kernels/clutter.py``): with a ``Canopy`` that is ``on``, each cell the walk visits
also tests the ray against that cell's canopy slab ``[bottom, top]`` (the part of the ray's
segment over the cell that lies inside it): the ray returns at the slab entry with probability
``1 - (1 - density)^L`` for ``L`` metres inside (one seeded draw per ray and cell, so a scan is
reproducible), unless it meets the ground first. Only ``cast_rays`` takes a canopy: the column
walk's invariant fails for a layer a low ray can pass under (and a porous one each ray crosses
with its own draws), so with clutter every ray is walked on its own. With the canopy off the
walk does exactly what it does without it.

Ray ``r`` of sample ``b`` starts at the sensor, above the heightfield's centre, and leaves
with unit direction ``directions[r]`` (sensor frame = world axes). The hit is written in the
sensor frame; rays with no return (no surface within range, outside ``[min_range, max_range]``
after noise, or dropped) are written as NaN.
"""

import functools

import warp as wp

from .clutter import STREAM_CANOPY
from .frames import dihedral_apply, sample_transform
from .heightfield import plane_height
from .rng import STREAM_RAYS, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator

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


@wp.struct
class Line:
    """The x-y path of a ray (or of the rays of one azimuth column) over the grid:
    ``(u0 + du s, v0 + dv s)`` in grid coordinates (cells) at ``s`` along it, and how it steps
    through cells along each axis (``step``: +1, -1 or 0; ``inv``: 1 / d, or 0 where it does not move)."""

    u0: float
    v0: float
    du: float
    dv: float
    inv_du: float
    inv_dv: float
    step_i: int
    step_j: int


@wp.struct
class Walk:
    """Where a walk along a line's cells stands: at ``s``, in cell ``(i, j)``, testing the cells
    of tile ``(open_ti, open_tj)`` one by one (any other tile it enters is first checked whole).
    Once ``over``, ``hit`` is where the ray met the surface (NO_HIT: nowhere before its end)."""

    s: float
    i: int
    j: int
    open_ti: int
    open_tj: int
    over: bool
    hit: float


@wp.func
def grid_line(u0: float, v0: float, du: float, dv: float) -> Line:
    """The line ``(u0 + du s, v0 + dv s)``, with its cell steps."""
    line = Line()
    line.u0 = u0
    line.v0 = v0
    line.du = du
    line.dv = dv
    line.step_i = axis_step(du)
    line.step_j = axis_step(dv)
    line.inv_du = inverse(du, line.step_i)
    line.inv_dv = inverse(dv, line.step_j)
    return line


@wp.func
def box_exit(line: Line, box: wp.vec4) -> float:
    """The ``s`` at which the line leaves the grid-coordinate box ``(lo_u, hi_u, lo_v, hi_v)``."""
    return wp.min(slab_exit(line.u0, line.du, box[0], box[1]), slab_exit(line.v0, line.dv, box[2], box[3]))


@wp.func
def tile_exits(line: Line, ti: int, tj: int, tile: int) -> wp.vec2:
    """The ``s`` at which the line leaves tile ``(ti, tj)`` along each axis."""
    return wp.vec2(
        next_boundary(line.u0, line.inv_du, ti * tile + wp.max(line.step_i, 0) * (tile - 1), line.step_i),
        next_boundary(line.v0, line.inv_dv, tj * tile + wp.max(line.step_j, 0) * (tile - 1), line.step_j),
    )


@wp.func
def cell_beyond_tile(line: Line, exits: wp.vec2, s: float, i: int, j: int, ti: int, tj: int, tile: int) -> wp.vec2i:
    """The cell the line enters when it leaves tile ``(ti, tj)`` at ``s``: the exit axis moves into
    the next tile; the other follows the line but never backwards (a ray through a tile corner
    must not bounce between two tiles)."""
    if exits[0] <= exits[1]:
        i_next = ti * tile + wp.max(line.step_i, 0) * tile - wp.max(-line.step_i, 0)
        return wp.vec2i(i_next, forward(j, cell_index(line.v0 + line.dv * s, line.step_j), line.step_j))
    j_next = tj * tile + wp.max(line.step_j, 0) * tile - wp.max(-line.step_j, 0)
    return wp.vec2i(forward(i, cell_index(line.u0 + line.du * s, line.step_i), line.step_i), j_next)


@wp.func
def corner_heights(heights: wp.array3d(dtype=float), b: int, i: int, j: int) -> wp.vec4:
    """Heights of cell ``(i, j)``'s corners (i, j), (i+1, j), (i, j+1), (i+1, j+1)."""
    return wp.vec4(heights[b, i, j], heights[b, i + 1, j], heights[b, i, j + 1], heights[b, i + 1, j + 1])


@wp.struct
class Canopy:
    """The clutter layer the rays are tested against (``kernels/clutter.py``): per-cell slabs
    ``[bottom, top]`` (world metres; empty where NaN or ``bottom >= top``) and ``density``
    (return probability per metre inside, 1 = solid); ``on = 0``: no clutter (arrays unused).
    ``key`` seeds the draws of one ray, ``metres`` is the ray's length per unit of the walk's ``s``."""

    bottom: wp.array3d(dtype=float)
    top: wp.array3d(dtype=float)
    density: wp.array3d(dtype=float)
    on: int
    key: int
    metres: float


@wp.func
def canopy_hit(canopy: Canopy, b: int, i: int, j: int, z0: float, dz: float, s0: float, s1: float) -> float:
    """Where the ray ``z0 + dz s``, ``s`` in ``[s0, s1]`` over cell ``(i, j)``, returns from the
    cell's canopy slab: its entry ``s``, drawn with probability ``1 - (1 - density)^L`` for the
    ``L`` metres it spends inside (1 for a solid slab); NO_HIT if it passes or misses the slab."""
    lo = canopy.bottom[b, i, j]
    hi = canopy.top[b, i, j]
    rho = canopy.density[b, i, j]
    if not (rho > 0.0 and hi > lo):  # empty (NaN fails too) or transparent
        return NO_HIT
    enter = s0
    leave = s1
    if dz != 0.0:
        s_lo = (lo - z0) / dz
        s_hi = (hi - z0) / dz
        enter = wp.max(s0, wp.min(s_lo, s_hi))
        leave = wp.min(s1, wp.max(s_lo, s_hi))
    elif z0 < lo or z0 > hi:
        return NO_HIT
    if not (leave > enter):
        return NO_HIT
    p = float(1.0)
    if rho < 1.0:
        p = 1.0 - wp.pow(1.0 - rho, (leave - enter) * canopy.metres)
    state = wp.rand_init(canopy.key, i * canopy.top.shape[2] + j)
    if wp.randf(state) < p:
        return enter
    return NO_HIT


@wp.func
def walk_start(line: Line) -> Walk:
    """A walk at the line's start (``s = 0``), in the cell it sets off into, no tile open yet."""
    w = Walk()
    w.s = 0.0
    w.i = cell_index(line.u0, line.step_i)
    w.j = cell_index(line.v0, line.step_j)
    w.open_ti = -1
    w.open_tj = -1
    w.over = False
    w.hit = NO_HIT
    return w


@wp.func
def ended(w: Walk, hit: float) -> Walk:
    """The walk, over at ``hit`` (or NO_HIT)."""
    w.over = True
    w.hit = hit
    return w


@wp.func
def resumed(w: Walk) -> Walk:
    """The walk, going on from where it stands for another ray along the same line (the next
    ring of a column): not over, and the tile it is in is checked whole again for that ray."""
    w.over = False
    w.hit = NO_HIT
    w.open_ti = -1
    w.open_tj = -1
    return w


@wp.func
def skip_tile(w: Walk, line: Line, exits: wp.vec2, s_tile: float, s_end: float, ti: int, tj: int, tile: int) -> Walk:
    """The walk past tile ``(ti, tj)``, which the ray passes above up to ``s_tile``: on in the
    cell beyond the boundary it leaves through, or over if its end comes first."""
    if s_tile >= s_end:
        return ended(w, NO_HIT)
    w.s = wp.max(w.s, s_tile)
    entered = cell_beyond_tile(line, exits, w.s, w.i, w.j, ti, tj, tile)
    w.i = entered[0]
    w.j = entered[1]
    return w


@wp.func
def cross_cell(w: Walk, line: Line, corner: wp.vec4, z: float, z0: float, dz: float, s_end: float, canopy: Canopy, b: int) -> Walk:
    """The walk through its cell (corner heights ``corner``; the ray at height ``z`` on entering):
    over where the ray meets the cell's triangles or returns from its canopy slab (the nearer of
    the two, if ``canopy.on``), else on in the neighbouring cell whose boundary
    the line crosses first (or over, if the ray's end lies in this cell). A cell whose corners all
    lie below the ray over its segment is passed without the exact test."""
    t_u = next_boundary(line.u0, line.inv_du, w.i, line.step_i)
    t_v = next_boundary(line.v0, line.inv_dv, w.j, line.step_j)
    s_cell = wp.max(wp.min(wp.min(t_u, t_v), s_end), w.s)
    hit = NO_HIT
    if wp.min(z, z0 + dz * s_cell) <= wp.max(wp.max(corner[0], corner[1]), wp.max(corner[2], corner[3])):
        hit = cell_hit(corner[0], corner[1], corner[2], corner[3], line.u0 - float(w.i), line.v0 - float(w.j), z0, line.du, line.dv, dz, w.s, s_cell)
    if canopy.on != 0:
        s_ground = s_cell
        if hit != NO_HIT:
            s_ground = hit  # the ray's path through the slab ends where it meets the ground
        c = canopy_hit(canopy, b, w.i, w.j, z0, dz, w.s, s_ground)
        if c != NO_HIT and (hit == NO_HIT or c < hit):
            hit = c
    if hit != NO_HIT:
        return ended(w, hit)
    if s_cell >= s_end:
        return ended(w, NO_HIT)
    if t_u <= t_v:
        w.i = w.i + line.step_i
    else:
        w.j = w.j + line.step_j
    w.s = s_cell
    return w


@wp.func
def walk(
    w: Walk,
    line: Line,
    heights: wp.array3d(dtype=float),
    tile_max: wp.array3d(dtype=float),
    b: int,
    tile: int,
    top: float,
    z0: float,
    dz: float,
    s_end: float,
    canopy: Canopy,
) -> Walk:
    """The walk of the ray ``(line, z0 + dz s)``, ``s`` in ``[0, s_end]``, over heightfield ``b``,
    from where ``w`` stands until it is over: the one cell walk every ray takes.

    The walk is an incremental DDA (Amanatides & Woo): each step moves to the neighbouring cell
    whose boundary the line crosses first, each boundary's ``s`` computed from its integer
    coordinate (no drift). A tile the ray passes above (``tile_max``) is skipped whole, the walk
    resuming in the cell beyond the tile boundary it leaves through. Cells are picked by the
    direction of travel, so a ray on a boundary is in the cell it enters and never stalls. The
    walk is over at its end, when the ray heads up above ``top`` (the terrain's highest point),
    when it leaves the grid, or where it meets the surface (or, if ``canopy.on``, returns from
    the canopy: ``tile_max`` and ``top`` must then cover the canopy tops); it stands in the cell
    where it ended.
    """
    H = heights.shape[1]
    W = heights.shape[2]
    while not w.over:
        z = z0 + dz * w.s
        if w.s >= s_end or (dz >= 0.0 and z > top) or w.i < 0 or w.i > H - 2 or w.j < 0 or w.j > W - 2:
            return ended(w, NO_HIT)
        ti = w.i // tile
        tj = w.j // tile
        if ti != w.open_ti or tj != w.open_tj:
            # entering a tile: skip it whole if the ray passes above its highest vertex
            exits = tile_exits(line, ti, tj, tile)
            s_tile = wp.min(wp.min(exits[0], exits[1]), s_end)
            if wp.min(z, z0 + dz * s_tile) > tile_max[b, ti, tj]:
                w = skip_tile(w, line, exits, s_tile, s_end, ti, tj, tile)
                continue
            w.open_ti = ti
            w.open_tj = tj
        w = cross_cell(w, line, corner_heights(heights, b, w.i, w.j), z, z0, dz, s_end, canopy, b)
    return w


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
    seeds: wp.array(dtype=int),
    augment: int,
    canopy: Canopy,
    points: wp.array2d(dtype=wp.vec3),
):
    """One thread per (scan, ray): every ray of every scan in the batch in one launch, each
    walked on its own (``walk`` with ``s`` = range in metres), against the clutter ``canopy``
    too if it is ``on`` (its draws seeded by ``(seed, b, r)``).

    Rays stop where they leave the square ``+-reach`` metres around the sensor (``reach <= 0``:
    the whole heightfield), so a caller that only bins points into a map casts no further.
    """
    b, r = wp.tid()
    seed = seeds[0]
    H = heights.shape[1]
    W = heights.shape[2]
    d = directions[r]
    line = grid_line(0.5 * float(H - 1), 0.5 * float(W - 1), d[0] / cell, d[1] / cell)
    t_end = wp.min(max_range, box_exit(line, reach_box(H, W, cell, reach)))
    ray_canopy = canopy
    if canopy.on != 0:
        ray_canopy.key = wp.randi(stream_state(seed, b, STREAM_CANOPY, r))
        ray_canopy.metres = 1.0
    w = walk(walk_start(line), line, heights, tile_max, b, tile, terrain_max[b], sensor_z[b], d[2], t_end, ray_canopy)
    write_return(points, b, r, d, w.hit, min_range, max_range, range_noise_std, dropout, seed, augment)


TILE_CELLS = 8  # cells per side of the max-height tiles (``tile_max``) the sim launches with


@functools.cache
def column_kernel(static_tile: bool = False, deferred: bool = False) -> wp.Kernel:
    """The column walk ``cast_columns`` in one of its variants, each giving the same points bit
    for bit (kept so a GPU run can time them: ``sim/switches.py``):

    - ``static_tile``: the tile size is ``TILE_CELLS``, compiled in, instead of the ``tile``
      argument (a constant divisor and loop bounds the compiler can fold);
    - ``deferred``: the walk only stores each ray's distance in ``ranges`` (``NO_HIT``: none) and
      ``write_returns`` then applies noise, dropout, range gate and transform per ray, so the walk
      kernel carries none of that code (``points`` is not written); otherwise the walk writes
      ``points`` itself (``ranges`` unused).
    """

    @wp.kernel(module="unique", enable_backward=False)
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
        seeds: wp.array(dtype=int),
        augment: int,
        points: wp.array2d(dtype=wp.vec3),
        ranges: wp.array2d(dtype=float),
    ):
        """One thread per (scan, azimuth column): all rings of a column in one walk.

        The rays of a column lie in one vertical plane through the sensor, and in that plane a
        lower ray meets the terrain no farther than a higher one (where the higher ray meets the
        surface, the lower one is already below it). So a single walk outward along the column's
        azimuth (``walk`` with ``s`` = horizontal distance in metres) serves every ring: the
        lowest ring not yet hit is tested cell by cell; when it is over, the next ring goes on from
        the same cell. A tile (or cell) the lowest ring passes above is passed by every higher ring
        too (no clutter here: see the module's docstring). Ring ``k`` is at height ``z0 + s tan(e_k)`` and range ``s / cos(e_k)``.
        Needs every ray off the vertical (``cos(e) > 0``) and rays ordered ring-major, lowest ring
        first (``LidarConfig.ray_directions``); hits equal ``cast_rays``' to float rounding. Thread
        ``c`` walks column ``first_column + c * column_step``, so processes can share a scan's columns.
        """
        b, c = wp.tid()
        seed = seeds[0]
        c = first_column + c * column_step
        H = heights.shape[1]
        W = heights.shape[2]
        n = tile
        if wp.static(static_tile):
            n = wp.static(TILE_CELLS)
        columns = directions.shape[0] // rings
        d0 = directions[c]
        h0 = wp.sqrt(d0[0] * d0[0] + d0[1] * d0[1])
        line = grid_line(0.5 * float(H - 1), 0.5 * float(W - 1), d0[0] / (h0 * cell), d0[1] / (h0 * cell))  # cells per metre of horizontal travel
        s_box = box_exit(line, reach_box(H, W, cell, reach))
        z0 = sensor_z[b]
        top = terrain_max[b]
        no_canopy = Canopy()
        no_canopy.on = 0
        w = walk_start(line)
        for k in range(rings):
            r = k * columns + c
            d = directions[r]
            h = wp.sqrt(d[0] * d[0] + d[1] * d[1])
            w = walk(resumed(w), line, heights, tile_max, b, n, top, z0, d[2] / h, wp.min(s_box, max_range * h), no_canopy)
            t = NO_HIT
            if w.hit != NO_HIT:
                t = w.hit / h
            if wp.static(deferred):
                ranges[b, r] = t
            else:
                write_return(points, b, r, d, t, min_range, max_range, range_noise_std, dropout, seed, augment)

    return cast_columns


cast_columns = column_kernel()


@wp.kernel
def write_returns(
    ranges: wp.array2d(dtype=float),
    directions: wp.array(dtype=wp.vec3),
    rings: int,
    first_column: int,
    column_step: int,
    min_range: float,
    max_range: float,
    range_noise_std: float,
    dropout: float,
    seeds: wp.array(dtype=int),
    augment: int,
    points: wp.array2d(dtype=wp.vec3),
):
    """The second pass of the deferred column walk: one thread per (scan, ring, column) writes
    the return of the distance the walk stored (``write_return``), for the columns
    ``first_column + c * column_step`` the walk was launched over."""
    b, k, c = wp.tid()
    seed = seeds[0]
    r = k * (directions.shape[0] // rings) + first_column + c * column_step
    write_return(points, b, r, directions[r], ranges[b, r], min_range, max_range, range_noise_std, dropout, seed, augment)
