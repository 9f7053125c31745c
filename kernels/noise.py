"""Fractal Brownian motion heightfields from Warp's Perlin noise (``wp.noise``).

``h(x, y) = amplitude * sqrt(2) * sum_o p^o * noise_o(f_o * (x, y)) / sum_o p^o`` with
``f_o = lacunarity^o / feature_size``: ``feature_size`` (metres) is the wavelength of the first
octave and ``amplitude`` (metres) bounds the heights (2-D Perlin noise lies in
``[-1/sqrt(2), 1/sqrt(2)]``, hence the ``sqrt(2)``). Each octave samples its own noise field at
its own random offset, so octaves are uncorrelated and the sensor's position is not pinned to a
lattice point (where Perlin noise is zero) of every octave.

Two ways to evaluate the same field:

- ``fractal_heightfield`` calls ``wp.noise`` per vertex and octave: one thread per vertex, the
  layout a GPU wants (coalesced writes, hashing is cheap next to memory).
- ``lattice_gradients`` + ``fractal_rows`` (the CPU path): a vertex grid is much finer than the
  coarse octaves' lattices, so hashing four gradients per vertex and octave repeats the same
  work many times. ``lattice_gradients`` reads each lattice point's gradient once, from Warp's
  own noise: at a lattice point the fade has zero slope, so ``wp.curlnoise`` there is exactly
  the rotated gradient ``wp.noise`` interpolates. ``fractal_rows`` then walks one row of
  vertices per thread, reloading the four corner gradients only when the row crosses a lattice
  line, and evaluates Perlin's interpolation with the same arithmetic as ``wp.noise``. Octaves
  whose lattice is finer than ``table_octaves`` allows fall back to ``wp.noise`` in the row loop.
"""

import warp as wp

from .rng import STREAM_TERRAIN, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator

PERLIN_2D_BOUND = wp.constant(0.70710678)


@wp.kernel
def octave_fields(seeds: wp.array(dtype=int), first: int, fields: wp.array2d(dtype=wp.uint32), offsets: wp.array2d(dtype=wp.vec2)):
    """Noise field (RNG state) and lattice offset of octave ``o`` of sample ``first + b``."""
    b, o = wp.tid()
    seed = seeds[0]
    state = stream_state(seed, first + b, STREAM_TERRAIN, o)
    offsets[b, o] = wp.vec2(wp.randf(state), wp.randf(state)) * 1024.0
    fields[b, o] = wp.rand_init(wp.randi(state))


@wp.func
def vertex_coordinate(k: int, n: int, cell: float, feature_size: float) -> float:
    """Vertex ``k`` of ``n`` along an axis, centred, in units of the first octave's wavelength."""
    return (float(k) - 0.5 * float(n - 1)) * cell / feature_size


@wp.func
def octave_frequency(lacunarity: float, o: int) -> float:
    """``lacunarity^o`` by repeated products, exactly as the octave loops accumulate it."""
    frequency = float(1.0)
    for _k in range(o):
        frequency *= lacunarity
    return frequency


@wp.func
def fade(t: float) -> float:
    """Perlin's quintic fade (``smootherstep``, as inside ``wp.noise``)."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@wp.func
def octave_sum(fields: wp.array2d(dtype=wp.uint32), offsets: wp.array2d(dtype=wp.vec2), b: int, p: wp.vec2, persistence: float,
               lacunarity: float) -> wp.vec2:
    """``(sum of weighted octaves of wp.noise at p, sum of the weights)`` for sample ``b``: octave
    ``o`` is its own field at its own offset, ``persistence**o`` strong and ``lacunarity**o`` finer."""
    total = float(0.0)
    weight = float(1.0)
    weights = float(0.0)
    frequency = float(1.0)
    for o in range(fields.shape[1]):
        total += weight * wp.noise(fields[b, o], p * frequency + offsets[b, o])
        weights += weight
        weight *= persistence
        frequency *= lacunarity
    return wp.vec2(total, weights)


@wp.kernel
def fractal_heightfield(
    fields: wp.array2d(dtype=wp.uint32),
    offsets: wp.array2d(dtype=wp.vec2),
    cell: float,
    persistence: float,
    lacunarity: float,
    feature_size: wp.array(dtype=float),
    amplitude: wp.array(dtype=float),
    heights: wp.array3d(dtype=float),
):
    """One thread per vertex, ``wp.noise`` per octave; ``feature_size``/``amplitude`` per sample."""
    b, i, j = wp.tid()
    p = wp.vec2(
        vertex_coordinate(i, heights.shape[1], cell, feature_size[b]),
        vertex_coordinate(j, heights.shape[2], cell, feature_size[b]),
    )
    s = octave_sum(fields, offsets, b, p, persistence, lacunarity)
    heights[b, i, j] = amplitude[b] * s[0] / (s[1] * PERLIN_2D_BOUND)


@wp.kernel
def lattice_gradients(
    fields: wp.array2d(dtype=wp.uint32),
    offsets: wp.array2d(dtype=wp.vec2),
    cell: float,
    lacunarity: float,
    feature_size: wp.array(dtype=float),
    rows: int,
    columns: int,
    origin: wp.array2d(dtype=wp.vec2i),
    gradients: wp.array4d(dtype=wp.vec2),
):
    """Row ``u`` of octave ``o``'s gradient table: the gradient of lattice point
    ``origin[b, o] + (u, v)`` of its noise field, for every ``v`` the octave needs.

    ``origin`` is one lattice cell below the grid's first vertex, so rounding in the row
    kernel can never step below the table. The table is sized for the finest octave; a coarser
    one fills only the part its grid spans (the last vertex's cell, its far corner and one more
    for rounding), and the row kernel never reads past it.
    """
    b, o, u = wp.tid()
    frequency = octave_frequency(lacunarity, o)
    x0 = vertex_coordinate(0, rows, cell, feature_size[b]) * frequency + offsets[b, o][0]
    y0 = vertex_coordinate(0, columns, cell, feature_size[b]) * frequency + offsets[b, o][1]
    corner = wp.vec2i(int(wp.floor(x0)) - 1, int(wp.floor(y0)) - 1)
    if u == 0:
        origin[b, o] = corner
    x1 = vertex_coordinate(rows - 1, rows, cell, feature_size[b]) * frequency + offsets[b, o][0]
    y1 = vertex_coordinate(columns - 1, columns, cell, feature_size[b]) * frequency + offsets[b, o][1]
    if u > int(wp.floor(x1)) - corner[0] + 2:
        return
    span = wp.min(int(wp.floor(y1)) - corner[1] + 3, gradients.shape[3])
    for v in range(span):
        point = wp.vec2(float(corner[0] + u), float(corner[1] + v))
        curl = wp.curlnoise(fields[b, o], point, wp.uint32(1), 2.0, 0.5)  # (-dn/dy, dn/dx)
        gradients[b, o, u, v] = wp.vec2(curl[1], -curl[0])


@wp.kernel
def fractal_rows(
    fields: wp.array2d(dtype=wp.uint32),
    offsets: wp.array2d(dtype=wp.vec2),
    gradients: wp.array4d(dtype=wp.vec2),
    origin: wp.array2d(dtype=wp.vec2i),
    table_octaves: int,
    cell: float,
    persistence: float,
    lacunarity: float,
    feature_size: wp.array(dtype=float),
    amplitude: wp.array(dtype=float),
    heights: wp.array3d(dtype=float),
):
    """Row ``i`` of heightfield ``b``: octaves below ``table_octaves`` from the gradient table."""
    b, i = wp.tid()
    rows = heights.shape[1]
    columns = heights.shape[2]
    last = gradients.shape[2] - 2
    px = vertex_coordinate(i, rows, cell, feature_size[b])
    for j in range(columns):
        heights[b, i, j] = 0.0
    weight = float(1.0)
    weights = float(0.0)
    frequency = float(1.0)
    for o in range(fields.shape[1]):
        offset = offsets[b, o]
        if o < table_octaves:
            qx = px * frequency + offset[0]
            fx = wp.floor(qx)
            dx = qx - fx
            sx = fade(dx)
            u = wp.clamp(int(fx) - origin[b, o][0], 0, last)
            fy = float(0.0)
            edge = float(-1.0e30)
            # corner gradients of the current lattice cell, x terms folded in
            a00 = float(0.0)
            a10 = float(0.0)
            a01 = float(0.0)
            a11 = float(0.0)
            c00 = float(0.0)
            c10 = float(0.0)
            c01 = float(0.0)
            c11 = float(0.0)
            step = cell / feature_size[b] * frequency  # lattice units per vertex, no division per vertex
            centre = 0.5 * float(columns - 1)
            for j in range(columns):
                qy = (float(j) - centre) * step + offset[1]
                if qy >= edge:  # crossed a lattice line (qy grows with j)
                    fy = wp.floor(qy)
                    edge = fy + 1.0
                    v = wp.clamp(int(fy) - origin[b, o][1], 0, last)
                    g00 = gradients[b, o, u, v]
                    g10 = gradients[b, o, u + 1, v]
                    g01 = gradients[b, o, u, v + 1]
                    g11 = gradients[b, o, u + 1, v + 1]
                    a00 = dx * g00[0]
                    a10 = (dx - 1.0) * g10[0]
                    a01 = dx * g01[0]
                    a11 = (dx - 1.0) * g11[0]
                    c00 = g00[1]
                    c10 = g10[1]
                    c01 = g01[1]
                    c11 = g11[1]
                dy = qy - fy
                v00 = a00 + dy * c00
                v10 = a10 + dy * c10
                v01 = a01 + (dy - 1.0) * c01
                v11 = a11 + (dy - 1.0) * c11
                xi0 = (v10 - v00) * sx + v00
                xi1 = (v11 - v01) * sx + v01
                heights[b, i, j] += weight * ((xi1 - xi0) * fade(dy) + xi0)
        else:
            for j in range(columns):
                p = wp.vec2(px, vertex_coordinate(j, columns, cell, feature_size[b]))
                heights[b, i, j] += weight * wp.noise(fields[b, o], p * frequency + offset)
        weights += weight
        weight *= persistence
        frequency *= lacunarity
    scale = amplitude[b] / (weights * PERLIN_2D_BOUND)
    for j in range(columns):
        heights[b, i, j] *= scale
