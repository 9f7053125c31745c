"""Fractal Brownian motion heightfields from Warp's Perlin noise (``wp.noise``).

``h(x, y) = amplitude * sqrt(2) * sum_o p^o * noise_o(f_o * (x, y)) / sum_o p^o`` with
``f_o = lacunarity^o / feature_size``: ``feature_size`` (metres) is the wavelength of the first
octave and ``amplitude`` (metres) bounds the heights (2-D Perlin noise lies in
``[-1/sqrt(2), 1/sqrt(2)]``, hence the ``sqrt(2)``). Each octave samples its own noise field at
its own random offset, so octaves are uncorrelated and the sensor's position is not pinned to a
lattice point (where Perlin noise is zero) of every octave.
"""

import warp as wp

from .rng import STREAM_TERRAIN, stream_state

PERLIN_2D_BOUND = wp.constant(0.70710678)


@wp.kernel
def octave_fields(seed: int, fields: wp.array2d(dtype=wp.uint32), offsets: wp.array2d(dtype=wp.vec2)):
    """Noise field (RNG state) and lattice offset of octave ``o`` of sample ``b``."""
    b, o = wp.tid()
    state = stream_state(seed, b, STREAM_TERRAIN, o)
    offsets[b, o] = wp.vec2(wp.randf(state), wp.randf(state)) * 1024.0
    fields[b, o] = wp.rand_init(wp.randi(state))


@wp.func
def fbm(
    fields: wp.array2d(dtype=wp.uint32),
    offsets: wp.array2d(dtype=wp.vec2),
    b: int,
    p: wp.vec2,
    persistence: float,
    lacunarity: float,
) -> float:
    """Normalised fBm in [-1, 1] at ``p`` (in units of the first octave's wavelength)."""
    total = float(0.0)
    weight = float(1.0)
    weights = float(0.0)
    frequency = float(1.0)
    for o in range(fields.shape[1]):
        total += weight * wp.noise(fields[b, o], p * frequency + offsets[b, o])
        weights += weight
        weight *= persistence
        frequency *= lacunarity
    return total / (weights * PERLIN_2D_BOUND)


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
    """One launch fills every heightfield of the batch.

    ``feature_size`` and ``amplitude`` are per sample so that one batch can mix reliefs.
    """
    b, i, j = wp.tid()
    H = heights.shape[1]
    W = heights.shape[2]
    x = (float(i) - 0.5 * float(H - 1)) * cell
    y = (float(j) - 0.5 * float(W - 1)) * cell
    p = wp.vec2(x, y) / feature_size[b]
    heights[b, i, j] = amplitude[b] * fbm(fields, offsets, b, p, persistence, lacunarity)
