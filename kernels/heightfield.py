"""The terrain surface of a heightfield and its max-height tiles.

Heightfield ``h[b, i, j]`` holds vertex heights; vertex (i, j) sits at
``x = (i - (H-1)/2) * cell``, ``y = (j - (W-1)/2) * cell``. In grid units ``u = x / cell + (H-1)/2``,
``v = y / cell + (W-1)/2`` the cell (i, j) spans ``[i, i+1] x [j, j+1]`` and is split along its
(i, j)-(i+1, j+1) diagonal into two triangles, so the surface is the same triangle mesh that a
``wp.Mesh`` built from the heightfield would hold:

- triangle A (a >= c): vertices (0,0), (1,0), (1,1)
- triangle B (a <  c): vertices (0,0), (1,1), (0,1)

with ``a = u - i`` and ``c = v - j`` the position inside the cell.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator


@wp.func
def plane_height(h00: float, h10: float, h01: float, h11: float, a: float, c: float, upper: bool) -> float:
    """Height of a cell's triangle A (``upper``, a >= c) or B, extended as a plane, at (a, c),
    from the heights of its corners (i, j), (i+1, j), (i, j+1), (i+1, j+1)."""
    if upper:
        return h00 + (h10 - h00) * a + (h11 - h10) * c
    return h00 + (h11 - h01) * a + (h01 - h00) * c


@wp.func
def cell_plane_height(
    heights: wp.array3d(dtype=float), b: int, i: int, j: int, a: float, c: float, upper: bool
) -> float:
    """Height of cell (i, j)'s triangle A (``upper``) or B, extended as a plane, at (a, c)."""
    return plane_height(heights[b, i, j], heights[b, i + 1, j], heights[b, i, j + 1], heights[b, i + 1, j + 1], a, c, upper)


@wp.func
def surface_height(heights: wp.array3d(dtype=float), b: int, u: float, v: float) -> float:
    """Height of the triangulated surface at grid coordinates (u, v), clamped to the domain."""
    H = heights.shape[1]
    W = heights.shape[2]
    u = wp.clamp(u, 0.0, float(H - 1))
    v = wp.clamp(v, 0.0, float(W - 1))
    i = wp.min(int(wp.floor(u)), H - 2)
    j = wp.min(int(wp.floor(v)), W - 2)
    a = u - float(i)
    c = v - float(j)
    return cell_plane_height(heights, b, i, j, a, c, a >= c)


@wp.kernel
def tile_max_heights(
    heights: wp.array3d(dtype=float),
    tile: int,
    tile_max: wp.array3d(dtype=float),
    terrain_max: wp.array(dtype=float),
):
    """Max height over the vertices of each ``tile x tile`` block of cells, and per terrain.

    Tile (ti, tj) covers cells ``[ti*tile, ti*tile + tile)``, so its vertices run to
    ``ti*tile + tile`` inclusive (clamped to the heightfield).
    """
    b, ti, tj = wp.tid()
    H = heights.shape[1]
    W = heights.shape[2]
    i_end = wp.min(ti * tile + tile, H - 1)
    j_end = wp.min(tj * tile + tile, W - 1)
    m = float(-1.0e30)
    for i in range(ti * tile, i_end + 1):
        for j in range(tj * tile, j_end + 1):
            m = wp.max(m, heights[b, i, j])
    tile_max[b, ti, tj] = m
    wp.atomic_max(terrain_max, b, m)


@wp.kernel
def sensor_heights(heights: wp.array3d(dtype=float), mount_height: float, sensor_z: wp.array(dtype=float)):
    """World height of each sensor: ``mount_height`` above the surface at the terrain's centre."""
    b = wp.tid()
    H = heights.shape[1]
    W = heights.shape[2]
    sensor_z[b] = surface_height(heights, b, 0.5 * float(H - 1), 0.5 * float(W - 1)) + mount_height
