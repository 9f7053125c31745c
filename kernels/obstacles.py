"""Obstacles stamped into heightfields: cylinders, boxes and rocks stand up; pits and ditches cut in.

Obstacles are sampled on the device (one thread per obstacle slot) and stamped by one thread per
heightfield vertex, so a whole batch takes two launches and never leaves the device. There is
no fixed limit on the count: each kind gets ``count_max`` slots per sample (dozens per map are
fine); every vertex tests every slot, so stamping time grows with the total.

Shapes (footprint in the x-y plane, centre ``center``, half extents ``half``, heading ``yaw``):

- cylinder: disc of radius ``half.x``, flat top at ``level``
- box:      rectangle ``2 half.x`` long (along yaw) by ``2 half.y`` wide, flat top at ``level``
- rock:     ellipsoidal cap of radius ``half.x``, apex at ``level``, rising from the local ground
- pit:      disc of radius ``half.x``; the ground inside drops by ``depth``
- ditch:    rectangle like a box; the ground inside drops by ``depth``

Positive tops are set above the ground at the obstacle's centre, so obstacles stand on slopes;
negative obstacles follow the terrain down, so a ditch across a hill keeps its depth.
"""

import warp as wp

from .heightfield import surface_height
from .rng import STREAM_OBSTACLES, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator

NONE = wp.constant(0)
CYLINDER = wp.constant(1)
BOX = wp.constant(2)
ROCK = wp.constant(3)
PIT = wp.constant(4)
DITCH = wp.constant(5)


@wp.struct
class ObstacleSpec:
    """How to draw obstacles of one kind (sizes are full widths / lengths, metres)."""

    kind: int
    count_min: int
    count_max: int
    width_min: float
    width_max: float
    length_min: float
    length_max: float
    height_min: float
    height_max: float


@wp.struct
class Obstacle:
    kind: int
    center: wp.vec2
    half: wp.vec2
    yaw: float
    level: float  # top height (cylinder, box, rock) or depth (pit, ditch), metres


@wp.kernel
def sample_obstacles(
    seeds: wp.array(dtype=int),
    first: int,
    specs: wp.array(dtype=ObstacleSpec),
    slot_spec: wp.array(dtype=int),
    slot_rank: wp.array(dtype=int),
    heights: wp.array3d(dtype=float),
    cell: float,
    region: float,
    keep_out: float,
    obstacles: wp.array2d(dtype=Obstacle),
):
    """Draw obstacle ``s`` of sample ``first + b`` (a batch split across processes draws the same).

    Slot ``s`` is the ``slot_rank[s]``-th possible obstacle of spec ``slot_spec[s]``; the spec's
    count is drawn once per sample (every slot of the spec draws the same number) and slots
    beyond it stay empty. Centres are uniform in ``[-region, region]^2`` and kept so that the
    footprint stays ``keep_out`` metres clear of the sensor (retrying up to 32 times).
    """
    b, s = wp.tid()
    seed = seeds[0]
    k = slot_spec[s]
    spec = specs[k]
    out = Obstacle()
    out.kind = NONE
    count_state = stream_state(seed, first + b, STREAM_OBSTACLES, k)
    count = wp.randi(count_state, spec.count_min, spec.count_max + 1)
    if slot_rank[s] >= count:
        obstacles[b, s] = out
        return
    state = stream_state(seed, first + b, STREAM_OBSTACLES, 65536 + s)
    # (wp.randf advances ``state`` in place, so it is called here, not in a helper)
    width = wp.randf(state, spec.width_min, spec.width_max)
    length = wp.randf(state, spec.length_min, spec.length_max)
    height = wp.randf(state, spec.height_min, spec.height_max)
    yaw = wp.randf(state, 0.0, 2.0 * wp.pi)
    half = wp.vec2(0.5 * width, 0.5 * width)
    if spec.kind == BOX or spec.kind == DITCH:
        half = wp.vec2(0.5 * length, 0.5 * width)
    reach = wp.length(half)
    for _attempt in range(32):
        cx = wp.randf(state, -region, region)
        cy = wp.randf(state, -region, region)
        center = wp.vec2(cx, cy)
        if wp.length(center) - reach >= keep_out:
            out.kind = spec.kind
            out.center = center
            out.half = half
            out.yaw = yaw
            out.level = height
            if spec.kind == CYLINDER or spec.kind == BOX or spec.kind == ROCK:
                H = heights.shape[1]
                W = heights.shape[2]
                u = center[0] / cell + 0.5 * float(H - 1)
                v = center[1] / cell + 0.5 * float(W - 1)
                out.level = surface_height(heights, b, u, v) + height
            break
    obstacles[b, s] = out


@wp.func
def local_coords(o: Obstacle, p: wp.vec2) -> wp.vec2:
    d = p - o.center
    c = wp.cos(o.yaw)
    s = wp.sin(o.yaw)
    return wp.vec2(c * d[0] + s * d[1], -s * d[0] + c * d[1])


@wp.func
def footprint(o: Obstacle, q: wp.vec2) -> float:
    """Normalised distance into the footprint: < 1 inside (round: r/R; rectangles: max-norm)."""
    if o.kind == BOX or o.kind == DITCH:
        return wp.max(wp.abs(q[0]) / o.half[0], wp.abs(q[1]) / o.half[1])
    return wp.length(q) / o.half[0]


@wp.kernel
def stamp_obstacles(
    obstacles: wp.array2d(dtype=Obstacle),
    cell: float,
    heights: wp.array3d(dtype=float),
):
    """Cut pits and ditches, then raise cylinders, boxes and rocks, at every vertex."""
    b, i, j = wp.tid()
    H = heights.shape[1]
    W = heights.shape[2]
    p = wp.vec2((float(i) - 0.5 * float(H - 1)) * cell, (float(j) - 0.5 * float(W - 1)) * cell)
    ground = heights[b, i, j]
    h = ground
    for s in range(obstacles.shape[1]):
        o = obstacles[b, s]
        if o.kind == PIT or o.kind == DITCH:
            if footprint(o, local_coords(o, p)) < 1.0:
                h = wp.min(h, ground - o.level)
    for s in range(obstacles.shape[1]):
        o = obstacles[b, s]
        if o.kind == CYLINDER or o.kind == BOX:
            if footprint(o, local_coords(o, p)) < 1.0:
                h = wp.max(h, o.level)
        elif o.kind == ROCK:
            r = footprint(o, local_coords(o, p))
            if r < 1.0:
                # ellipsoidal cap: rises from the ground at the rim to ``level`` at the centre
                top = o.level
                h = wp.max(h, ground + (top - ground) * wp.sqrt(1.0 - r * r))
    heights[b, i, j] = h
