"""The anchors: other libraries timed on the same work as ours, where they are installed.

- :func:`noise_anchor`: FastNoiseLite (pyfastnoiselite) Perlin fBm, same octaves, lacunarity,
  gain and first wavelength, one thread, on the same number of samples as NOISE.
- :func:`rays_anchor`: Open3D's ``RaycastingScene`` (Embree) on the triangle mesh of RAYS'
  heightfield (:func:`heightfield_triangles`, same diagonal), cast-only and fresh (BVH build +
  cast), with all threads and one; its hit distances must agree with ours to 1 mm
  (:func:`compare_hits`). :func:`open3d_hits` is the same cast, untimed.

Both libraries are optional: imported inside the functions, and an anchor that cannot be
imported is reported (``available: false`` and the reason), never raised.
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..sim import TerrainConfig
from .harness import SEED, dist_version, summarize, time_calls, unavailable

AGREEMENT_TOLERANCE_M = 1e-3  # RAYS: our hit distances and Open3D's must agree to 1 mm


# ------------------------------------------------------------------------------- NOISE
def _noise_coords(batch: int, size: int, cell: float) -> np.ndarray:
    """float32 ``(2, batch*size*size)`` metre coordinates of ``batch`` fields side by side."""
    axis = (np.arange(size) - 0.5 * (size - 1)) * cell
    x, y = np.meshgrid(axis, axis, indexing="ij")
    k = np.arange(batch)
    spacing = 2.0 * size * cell  # fields side by side, 8 per row, coordinates stay small
    ox = ((k % 8) * spacing)[:, None, None]
    oy = ((k // 8) * spacing)[:, None, None]
    return np.ascontiguousarray(np.stack([(x[None] + ox).ravel(), (y[None] + oy).ravel()]).astype(np.float32))


def noise_anchor(batch: int, size: int, cfg: TerrainConfig, repeats: int, ours_per_s: float) -> dict:
    """FastNoiseLite (pyfastnoiselite) Perlin fBm on the same vertices, in one thread.

    Coordinates are metres (vertex (i, j) of field k at ``x = (i - (size-1)/2) * cell`` plus a
    per-field offset, so the 64 fields are 64 different terrains) and ``frequency = 1 /
    feature_size``: the first octave has the same wavelength as ours (8 m in NOISE), then ``octaves``
    octaves with the same lacunarity and gain. ``gen_from_coords`` is a single-threaded Cython
    loop; the float32 (2, N) coordinates exist before the clock, as our vertex grid does.
    """
    try:
        from pyfastnoiselite.pyfastnoiselite import FastNoiseLite, FractalType, NoiseType
    except (ImportError, OSError) as err:
        return unavailable("pyfastnoiselite", err)
    noise = FastNoiseLite(SEED)
    noise.noise_type = NoiseType.NoiseType_Perlin
    noise.fractal_type = FractalType.FractalType_FBm
    noise.fractal_octaves = int(cfg.octaves)
    noise.fractal_lacunarity = float(cfg.lacunarity)
    noise.fractal_gain = float(cfg.persistence)
    noise.frequency = 1.0 / float(cfg.feature_size)
    coords = _noise_coords(batch, size, cfg.cell)
    samples = int(coords.shape[1])
    out = {}

    def run():
        out["values"] = noise.gen_from_coords(coords)

    timing = summarize(time_calls(run, "cpu", repeats))
    values = np.asarray(out["values"])
    per_s = samples / timing["median_s"]
    return {
        "available": True, "library": "pyfastnoiselite", "version": dist_version("pyfastnoiselite"), "threads": 1,
        "noise_type": "Perlin", "fractal_type": "FBm", "octaves": int(cfg.octaves), "lacunarity": float(cfg.lacunarity),
        "gain": float(cfg.persistence), "frequency_per_m": 1.0 / float(cfg.feature_size), "samples": samples,
        "value_range": [float(values.min()), float(values.max())], **timing,
        "samples_per_s": per_s, "ours_over_anchor": ours_per_s / per_s,
    }


# ------------------------------------------------------------------------------- RAYS
def heightfield_triangles(heights: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The triangle mesh our ray caster intersects: ``(H*W, 3)`` float32 vertices, vertex
    (i, j) at ``((i - (H-1)/2) cell, (j - (W-1)/2) cell, heights[i, j])``, and ``(2 (H-1)(W-1), 3)``
    uint32 triangles, each cell split along its (i, j)-(i+1, j+1) diagonal as in
    ``kernels/heightfield.py``: (i,j)-(i+1,j)-(i+1,j+1) (triangle A) and (i,j)-(i+1,j+1)-(i,j+1) (B).
    """
    heights = np.asarray(heights, dtype=np.float32)
    H, W = heights.shape
    i, j = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    vertices = np.stack([(i - 0.5 * (H - 1)) * cell, (j - 0.5 * (W - 1)) * cell, heights], -1).reshape(-1, 3)
    a, b = np.meshgrid(np.arange(H - 1), np.arange(W - 1), indexing="ij")
    v00, v10, v01, v11 = ((a * W + b).ravel(), ((a + 1) * W + b).ravel(), (a * W + b + 1).ravel(), ((a + 1) * W + b + 1).ravel())
    triangles = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(triangles, dtype=np.uint32)


def _open3d_rays(directions: np.ndarray, sensor_z: float) -> np.ndarray:
    """Open3D's ``(N, 6)`` float32 rays: origin ``(0, 0, sensor_z)``, then the direction."""
    d = np.asarray(directions, dtype=np.float32)
    origin = np.broadcast_to(np.array([0.0, 0.0, sensor_z], dtype=np.float32), d.shape)
    return np.ascontiguousarray(np.concatenate([origin, d], 1), dtype=np.float32)


def _returns(t: np.ndarray, lidar) -> np.ndarray:
    """Open3D hit distances as our LIDAR reports them: NaN outside ``[min_range, max_range]``."""
    t = np.asarray(t, dtype=np.float64)
    return np.where(np.isfinite(t) & (t >= lidar.min_range) & (t <= lidar.max_range), t, np.nan)


def open3d_hits(heights: np.ndarray, cell: float, lidar, sensor_z: float, nthreads: int = 0) -> np.ndarray:
    """Distances along ``lidar.ray_directions()`` from ``(0, 0, sensor_z)`` to the heightfield's
    mesh (:func:`heightfield_triangles`) by Open3D's ``RaycastingScene``; NaN where our LIDAR
    would report no return (no hit, or outside ``[min_range, max_range]``). Needs open3d."""
    import open3d as o3d

    vertices, triangles = heightfield_triangles(heights, cell)
    scene = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
    t = scene.cast_rays(o3d.core.Tensor(_open3d_rays(lidar.ray_directions(), sensor_z)), nthreads=nthreads)["t_hit"].numpy()
    return _returns(t, lidar)


def compare_hits(ours: np.ndarray, anchor: np.ndarray, tolerance: float = AGREEMENT_TOLERANCE_M) -> dict:
    """Agreement of two per-ray distance arrays (NaN = no return)."""
    ours, anchor = np.asarray(ours, dtype=np.float64), np.asarray(anchor, dtype=np.float64)
    hit_ours, hit_anchor = np.isfinite(ours), np.isfinite(anchor)
    both = hit_ours & hit_anchor
    diff = np.abs(ours[both] - anchor[both])
    within = int((diff <= tolerance).sum())
    return {
        "rays": int(ours.size),
        "both_hit": int(both.sum()),
        "both_hit_within_tolerance": within,
        "within_tolerance_fraction": within / int(both.sum()) if both.any() else math.nan,
        "only_ours_hit": int((hit_ours & ~hit_anchor).sum()),
        "only_anchor_hit": int((hit_anchor & ~hit_ours).sum()),
        "max_abs_diff_m": float(diff.max()) if diff.size else math.nan,
        "tolerance_m": float(tolerance),
        "agree": bool(within == int(both.sum()) and not (hit_ours ^ hit_anchor).any()),
    }


def _rate_entry(timing: dict, rays: int, ours_per_s: float) -> dict:
    """An anchor timing with its rays/s and our throughput over it."""
    per_s = rays / timing["median_s"]
    return {**timing, "rays_per_s": per_s, "ours_over_anchor": ours_per_s / per_s}


def rays_anchor(heights: np.ndarray, cell: float, lidar, sensor_z: float, ours: np.ndarray, ours_per_s: float, repeats: int) -> dict:
    """Open3D ``RaycastingScene`` (Embree BVH) on the same mesh and rays.

    Open3D builds its BVH lazily, at the first query after ``add_triangles``: "fresh" times a new
    scene, ``add_triangles`` and the first ``cast_rays`` (what a new terrain costs: our
    caster's equivalent is the whole ``trace``, tile build included); "cast" times
    ``cast_rays`` on the built scene. Each with all threads (``nthreads=0``, Open3D's default)
    and with one (``nthreads=1`` for the scene and the cast). The mesh's vertex and index
    arrays are made before the clock, as our heightfield is.
    """
    try:
        import open3d as o3d
    except (ImportError, OSError) as err:
        return unavailable("open3d", err)
    vertices, triangles = heightfield_triangles(heights, cell)
    rays = _open3d_rays(lidar.ray_directions(), sensor_z)
    n = rays.shape[0]
    runs = []
    anchor_t = None
    for label, nthreads in (("all", 0), ("1", 1)):
        state = {}

        def fresh(nthreads=nthreads, state=state):
            scene = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
            scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
            state["scene"] = scene
            state["t"] = scene.cast_rays(o3d.core.Tensor(rays), nthreads=nthreads)["t_hit"].numpy()

        def cast(nthreads=nthreads, state=state):
            state["t"] = state["scene"].cast_rays(o3d.core.Tensor(rays), nthreads=nthreads)["t_hit"].numpy()

        fresh_timing = summarize(time_calls(fresh, "cpu", repeats))
        cast_timing = summarize(time_calls(cast, "cpu", repeats))
        if anchor_t is None:
            anchor_t = state["t"]
        runs.append({
            "threads": label,
            "nthreads_arg": nthreads,
            "fresh": _rate_entry(fresh_timing, n, ours_per_s),
            "cast": _rate_entry(cast_timing, n, ours_per_s),
            "build_s": max(fresh_timing["median_s"] - cast_timing["median_s"], 0.0),
        })
    return {
        "available": True, "library": "open3d", "version": dist_version("open3d", "open3d-cpu"), "cpu_count": os.cpu_count(),
        "triangles": int(triangles.shape[0]), "rays": int(n), "runs": runs,
        "agreement": compare_hits(ours, _returns(anchor_t, lidar)),
    }
