"""The ground-truth elevation map: the true surface averaged over each map cell.

Each map cell averages ``samples x samples`` points of the triangulated surface placed at the
centres of a regular sub-grid of the cell, so obstacle edges cut through a cell give the
partial height they should and a plane gives its exact value at the cell's centre. Heights are
in the sensor frame (minus the sensor's world height); the augmentation transform of the sample
is undone to find where a map cell lies on the terrain.
"""

import warp as wp

from .frames import dihedral_invert, sample_transform
from .heightfield import surface_height

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator


@wp.func
def subcell_point(p: int, q: int, si: int, sj: int, half: float, step: float, map_cell: float, d: int, cell: float, H: int, W: int) -> wp.vec2:
    """Terrain grid coordinates ``(u, v)`` of sub-cell point ``(si, sj)`` of map cell ``(p, q)``
    (``step = 1 / samples`` of the cell, ``half = (S - 1) / 2``), the sample's transform ``d`` undone."""
    x = (float(p) - half - 0.5 + (float(si) + 0.5) * step) * map_cell
    y = (float(q) - half - 0.5 + (float(sj) + 0.5) * step) * map_cell
    w = dihedral_invert(d, wp.vec2(x, y))
    return wp.vec2(w[0] / cell + 0.5 * float(H - 1), w[1] / cell + 0.5 * float(W - 1))


@wp.kernel
def cell_mean_heights(
    heights: wp.array3d(dtype=float),
    cell: float,
    sensor_z: wp.array(dtype=float),
    map_cell: float,
    samples: int,
    seeds: wp.array(dtype=int),
    augment: int,
    target: wp.array4d(dtype=float),
):
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
            acc += surface_height(heights, b, uv[0], uv[1])
    target[b, 0, p, q] = acc * step * step - sensor_z[b]
