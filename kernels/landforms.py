"""Landforms laid on fBm terrain: a planar tilt, low-frequency relief, terraces, closed
depressions and gullies, batched over the whole batch.

``draw_landforms`` draws every sample's parameters on the device (one thread per sample, from
the sample's terrain stream at offsets past the fBm octaves', so sample ``first + b`` depends
only on ``(seed, first + b)``); one kernel per stage then applies them at every vertex:

- ``add_relief``:  ``amplitude * fBm`` of ``relief octaves`` octaves, the first of wavelength
  ``wavelength`` metres (each next one twice finer and half as strong), heights within
  +-``amplitude``, as ``kernels/noise.py`` normalises them.
- ``add_tilt``:    the plane ``h += g . (x, y)`` through the sensor (the map's centre), with
  ``|g| = tan(slope)``.
- ``add_terraces``: ``h' = phase + rise * (floor(u) + ramp(frac(u)))``, ``u = (h - phase) / rise``,
  ``ramp(f) = smoothstep(clamp((f - tread) / (1 - tread), 0, 1))``: flat treads for the first
  ``tread`` share of each step, then a smooth riser of height ``rise`` (``tread = 0`` is
  ``rise * (floor(u) + smoothstep(frac(u)))``). Continuous with a continuous slope.
- ``carve``:       closed depressions (bowls ``depth * (1 - (r/R)^2)^2``, minimum ``-depth`` at
  the centre, level at the rim) and gullies (a channel along the meandering curve
  ``n = meander * sin(k s + phase)`` in the gully's frame, cross-section
  ``depth * mix(V(t), U(t), shape)`` with ``t`` the distance to the curve over the half width,
  ``V(t) = 1 - smoothstep(t)``, ``U(t) = 1 - smoothstep(2 t - 1)``), the deepest cut wins where
  they overlap. Every profile has zero slope at its rim, so the cuts are smooth.
"""

import warp as wp

from .noise import PERLIN_2D_BOUND, octave_sum
from .rng import STREAM_TERRAIN, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator

# offsets in the terrain stream, past the fBm octaves' (0..15)
TILT_OFFSET = wp.constant(1048576)
RELIEF_OFFSET = wp.constant(2097152)  # + octave; the draw of wavelength and amplitude at + 64
TERRACE_OFFSET = wp.constant(3145728)
DEPRESSION_OFFSET = wp.constant(4194304)  # count at +0, slot s at + 1 + s
GULLY_OFFSET = wp.constant(5242880)  # count at +0, slot s at + 1 + s


@wp.struct
class LandformSpec:
    """The ranges draws are made from (angles in radians, lengths in metres)."""

    slope_min: float
    slope_max: float
    relief_wavelength_min: float
    relief_wavelength_max: float
    relief_amplitude_min: float
    relief_amplitude_max: float
    terrace_probability: float
    terrace_rise_min: float
    terrace_rise_max: float
    terrace_tread_min: float
    terrace_tread_max: float
    depressions_min: int
    depressions_max: int
    depression_radius_min: float
    depression_radius_max: float
    depression_depth_min: float
    depression_depth_max: float
    gullies_min: int
    gullies_max: int
    gully_width_min: float
    gully_width_max: float
    gully_depth_min: float
    gully_depth_max: float
    gully_meander_max: float
    gully_wavelength_min: float
    gully_wavelength_max: float
    extent: float  # centres are drawn in [-extent, extent]^2


@wp.struct
class SampleLandforms:
    """One sample's draws; ``terrace_rise = 0``: no terraces."""

    gradient: wp.vec2
    relief_wavelength: float
    relief_amplitude: float
    terrace_rise: float
    terrace_tread: float
    terrace_phase: float


@wp.struct
class Depression:
    """A bowl; ``depth = 0``: an empty slot."""

    center: wp.vec2
    radius: float
    depth: float


@wp.struct
class Gully:
    """A channel; ``depth = 0``: an empty slot. ``heading`` is the direction of its axis."""

    center: wp.vec2
    heading: float
    half_width: float
    depth: float
    meander: float
    wavenumber: float
    phase: float
    shape: float  # 0: V, 1: U


@wp.kernel
def draw_landforms(
    seeds: wp.array(dtype=int),
    first: int,
    spec: LandformSpec,
    params: wp.array(dtype=SampleLandforms),
    fields: wp.array2d(dtype=wp.uint32),
    offsets: wp.array2d(dtype=wp.vec2),
    depressions: wp.array2d(dtype=Depression),
    gullies: wp.array2d(dtype=Gully),
):
    """Every draw of sample ``first + b``: tilt, relief noise fields, terraces, depressions, gullies.

    Each use draws from its own offset of the terrain stream, so turning one landform on or
    changing its count range leaves the others' draws as they were.
    """
    b = wp.tid()
    seed = seeds[0]
    sample = first + b
    out = SampleLandforms()
    # (wp.randf advances ``state`` in place, so draws are made here, not in helpers)
    state = stream_state(seed, sample, STREAM_TERRAIN, TILT_OFFSET)
    slope = wp.randf(state, spec.slope_min, spec.slope_max)
    direction = wp.randf(state, 0.0, 2.0 * wp.pi)
    out.gradient = wp.tan(slope) * wp.vec2(wp.cos(direction), wp.sin(direction))
    for o in range(fields.shape[1]):
        octave = stream_state(seed, sample, STREAM_TERRAIN, RELIEF_OFFSET + o)
        offsets[b, o] = wp.vec2(wp.randf(octave), wp.randf(octave)) * 1024.0
        fields[b, o] = wp.rand_init(wp.randi(octave))
    state = stream_state(seed, sample, STREAM_TERRAIN, RELIEF_OFFSET + 64)
    out.relief_wavelength = wp.randf(state, spec.relief_wavelength_min, spec.relief_wavelength_max)
    out.relief_amplitude = wp.randf(state, spec.relief_amplitude_min, spec.relief_amplitude_max)
    state = stream_state(seed, sample, STREAM_TERRAIN, TERRACE_OFFSET)
    on = wp.randf(state) < spec.terrace_probability
    rise = wp.randf(state, spec.terrace_rise_min, spec.terrace_rise_max)
    out.terrace_tread = wp.randf(state, spec.terrace_tread_min, spec.terrace_tread_max)
    out.terrace_phase = wp.randf(state, 0.0, rise)
    out.terrace_rise = 0.0
    if on:
        out.terrace_rise = rise
    params[b] = out
    state = stream_state(seed, sample, STREAM_TERRAIN, DEPRESSION_OFFSET)
    count = wp.randi(state, spec.depressions_min, spec.depressions_max + 1)
    for s in range(depressions.shape[1]):
        d = Depression()
        slot = stream_state(seed, sample, STREAM_TERRAIN, DEPRESSION_OFFSET + 1 + s)
        d.center = wp.vec2(wp.randf(slot, -spec.extent, spec.extent), wp.randf(slot, -spec.extent, spec.extent))
        d.radius = wp.randf(slot, spec.depression_radius_min, spec.depression_radius_max)
        d.depth = wp.randf(slot, spec.depression_depth_min, spec.depression_depth_max)
        if s >= count:
            d.depth = 0.0
        depressions[b, s] = d
    state = stream_state(seed, sample, STREAM_TERRAIN, GULLY_OFFSET)
    count = wp.randi(state, spec.gullies_min, spec.gullies_max + 1)
    for s in range(gullies.shape[1]):
        g = Gully()
        slot = stream_state(seed, sample, STREAM_TERRAIN, GULLY_OFFSET + 1 + s)
        g.center = wp.vec2(wp.randf(slot, -spec.extent, spec.extent), wp.randf(slot, -spec.extent, spec.extent))
        g.heading = wp.randf(slot, 0.0, wp.pi)
        g.half_width = 0.5 * wp.randf(slot, spec.gully_width_min, spec.gully_width_max)
        g.depth = wp.randf(slot, spec.gully_depth_min, spec.gully_depth_max)
        g.meander = wp.randf(slot, 0.0, spec.gully_meander_max)
        g.wavenumber = 2.0 * wp.pi / wp.randf(slot, spec.gully_wavelength_min, spec.gully_wavelength_max)
        g.phase = wp.randf(slot, 0.0, 2.0 * wp.pi)
        g.shape = wp.randf(slot)
        if s >= count:
            g.depth = 0.0
        gullies[b, s] = g


@wp.func
def vertex_position(i: int, j: int, rows: int, columns: int, cell: float) -> wp.vec2:
    """Vertex ``(i, j)`` in metres, the grid centred on the sensor."""
    return wp.vec2((float(i) - 0.5 * float(rows - 1)) * cell, (float(j) - 0.5 * float(columns - 1)) * cell)


@wp.func
def smoothstep01(t: float) -> float:
    """``3 t^2 - 2 t^3`` on [0, 1], clamped outside: zero slope at both ends."""
    c = wp.clamp(t, 0.0, 1.0)
    return c * c * (3.0 - 2.0 * c)


@wp.func
def terrace_height(h: float, rise: float, tread: float, phase: float) -> float:
    """``h`` quantised into smooth steps of height ``rise``, flat for the first ``tread`` of each."""
    u = (h - phase) / rise
    k = wp.floor(u)
    ramp = smoothstep01((u - k - tread) / (1.0 - tread))
    return phase + rise * (k + ramp)


@wp.func
def bowl(d: Depression, p: wp.vec2) -> float:
    """How deep depression ``d`` cuts at ``p``: ``depth * (1 - (r/R)^2)^2`` inside, 0 outside."""
    t2 = wp.length_sq(p - d.center) / (d.radius * d.radius)
    if t2 >= 1.0:
        return 0.0
    return d.depth * (1.0 - t2) * (1.0 - t2)


@wp.func
def channel(g: Gully, p: wp.vec2) -> float:
    """How deep gully ``g`` cuts at ``p`` (distance to the meandering centre line, to first order)."""
    q = p - g.center
    c = wp.cos(g.heading)
    s = wp.sin(g.heading)
    along = c * q[0] + s * q[1]
    across = -s * q[0] + c * q[1]
    angle = g.wavenumber * along + g.phase
    lateral = g.meander * g.wavenumber * wp.cos(angle)
    distance = wp.abs(across - g.meander * wp.sin(angle)) / wp.sqrt(1.0 + lateral * lateral)
    t = distance / g.half_width
    if t >= 1.0:
        return 0.0
    v = 1.0 - smoothstep01(t)
    u = 1.0 - smoothstep01(2.0 * t - 1.0)
    return g.depth * (v + (u - v) * g.shape)


@wp.kernel
def add_relief(
    fields: wp.array2d(dtype=wp.uint32),
    offsets: wp.array2d(dtype=wp.vec2),
    params: wp.array(dtype=SampleLandforms),
    cell: float,
    heights: wp.array3d(dtype=float),
):
    """Add each sample's low-frequency fBm (octaves ``fields.shape[1]``) at every vertex."""
    b, i, j = wp.tid()
    sample = params[b]
    p = vertex_position(i, j, heights.shape[1], heights.shape[2], cell) / sample.relief_wavelength
    s = octave_sum(fields, offsets, b, p, 0.5, 2.0)
    heights[b, i, j] += sample.relief_amplitude * s[0] / (s[1] * PERLIN_2D_BOUND)


@wp.kernel
def add_tilt(params: wp.array(dtype=SampleLandforms), cell: float, heights: wp.array3d(dtype=float)):
    """Add each sample's plane through the centre at every vertex."""
    b, i, j = wp.tid()
    p = vertex_position(i, j, heights.shape[1], heights.shape[2], cell)
    heights[b, i, j] += wp.dot(params[b].gradient, p)


@wp.kernel
def add_terraces(params: wp.array(dtype=SampleLandforms), heights: wp.array3d(dtype=float)):
    """Quantise each terraced sample's heights into smooth steps (samples with ``rise = 0`` keep theirs)."""
    b, i, j = wp.tid()
    sample = params[b]
    if sample.terrace_rise > 0.0:
        heights[b, i, j] = terrace_height(heights[b, i, j], sample.terrace_rise, sample.terrace_tread, sample.terrace_phase)


@wp.kernel
def carve(
    depressions: wp.array2d(dtype=Depression),
    gullies: wp.array2d(dtype=Gully),
    cell: float,
    heights: wp.array3d(dtype=float),
):
    """Lower every vertex by the deepest depression or gully cut there."""
    b, i, j = wp.tid()
    p = vertex_position(i, j, heights.shape[1], heights.shape[2], cell)
    cut = float(0.0)
    for s in range(depressions.shape[1]):
        d = depressions[b, s]
        if d.depth > 0.0:
            cut = wp.max(cut, bowl(d, p))
    for s in range(gullies.shape[1]):
        g = gullies[b, s]
        if g.depth > 0.0:
            cut = wp.max(cut, channel(g, p))
    heights[b, i, j] -= cut
