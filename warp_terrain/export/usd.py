"""USD export of terrains, LIDAR scans and reconstructed elevation maps (``export_usd``).

The stage (``.usda`` text or ``.usdc`` crate, chosen by the path's suffix) is Z-up with
``metersPerUnit = 1`` and its default prim ``/World``. For one ``(H, W)`` heightfield it holds::

    /World                      Xform
      Terrain                   Mesh: the heightfield, in its own (world) frame
      Sensor                    Xform translated to (0, 0, sensor_z): the sensor frame
        LidarPoints             Points: the scan's returns, sensor-frame coordinates (optional)
      Reconstruction            Xform translated to (dx, 0, sensor_z), beside the terrain (optional)
        Map                     Mesh: the reconstructed elevation map, sensor-frame heights
      ReconstructionError       Xform beside the reconstruction (only with ``target``)
        Map                     Mesh: the same map coloured by |reconstruction - target|

A batch ``(B, H, W)`` is written as one prim per sample, ``/World/Sample_0000`` ... each holding
the layout above and translated ``b * pitch`` along +y, so a viewer shows one row per sample:
terrain | reconstruction | error. (One prim per sample rather than time samples: every sample
can have its own point count and stays visible and addressable at once; a time-sampled mesh
would need a fixed topology and shows one sample at a time.)

A map reconstructed from a real cloud has no terrain beside it: ``export_reconstruction``
writes ``/World/Sensor/LidarPoints`` and ``/World/Reconstruction/Map`` in the sensor frame.

Geometry follows the design contract: vertex ``(i, j)`` of an ``(H, W)`` heightfield is at
``x = (i - (H-1)/2) * cell``, ``y = (j - (W-1)/2) * cell``, ``z = h[i, j]`` (stored as float32,
so the mesh's z equal ``h.astype(float32)`` exactly). Each cell is split into the two triangles
the simulator's ray caster intersects, ``(i,j),(i+1,j),(i+1,j+1)`` and ``(i,j),(i+1,j+1),(i,j+1)``,
counter-clockwise seen from above (``orientation = rightHanded``: face normals point up),
``subdivisionScheme = none``. Per-vertex normals (central differences of the heightfield) and
per-vertex ``displayColor`` (a matplotlib colormap of height, one colour scale per sample shared
by terrain and reconstruction) are written with the mesh; ``extent`` is set on every boundable.
Everything is built with numpy and handed to USD as whole arrays (``Vt.*Array.FromNumpy``):
no Python loop runs over vertices, so a 2048 x 2048 terrain exports in seconds.

The file is written atomically: the stage is built in memory, exported to a temporary file with
the same suffix in the target folder and renamed over ``path``; on any failure nothing is left.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import matplotlib
import numpy as np
import torch
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, Vt

from ..core.atomic import atomic_path

__all__ = ["USD_SUFFIXES", "check_usd_path", "export_reconstruction", "export_usd", "grid_faces", "grid_normals", "grid_points"]

USD_SUFFIXES = (".usda", ".usdc")


# ------------------------------------------------------------------------------ checks
def check_usd_path(path) -> Path:
    """``path`` as a ``Path`` if it can be written: a ``.usda``/``.usdc`` name in an existing,
    writable folder; else ``ValueError`` naming the problem and the path."""
    try:
        path = Path(os.fspath(path))
    except TypeError:
        raise ValueError(f"path={path!r}: expected a file path ending in .usda or .usdc") from None
    if path.suffix not in USD_SUFFIXES:
        raise ValueError(f"path={str(path)!r}: unsupported suffix {path.suffix!r}; use .usda (text) or .usdc (binary)")
    if not path.stem or path.name.startswith("."):
        raise ValueError(f"path={str(path)!r}: needs a file name before the suffix")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise ValueError(f"path={str(path)!r}: the folder {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise ValueError(f"path={str(path)!r}: {str(parent)!r} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"path={str(path)!r}: no permission to write in the folder {str(parent)!r}")
    if path.is_dir():
        raise ValueError(f"path={str(path)!r}: is a folder, not a file name")
    return path


def _as_array(name: str, value) -> np.ndarray:
    """A numpy view/copy of a numpy array, torch tensor, Warp array or nested sequence of numbers."""
    try:

        if isinstance(value, torch.Tensor):
            value = value.detach().cpu().numpy()
    except ImportError:  # pragma: no cover - torch is a dependency
        pass
    if not isinstance(value, np.ndarray) and hasattr(value, "numpy") and callable(value.numpy):
        value = value.numpy()  # a Warp array
    try:
        array = np.asarray(value)
    except Exception:
        raise ValueError(f"{name}: expected a numpy array or torch tensor, got {type(value).__name__}") from None
    if array.dtype == bool or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name}: expected real numbers, got dtype {array.dtype}")
    return array


def _check_grid(name: str, value, batch: int | None) -> np.ndarray:
    """A float32 ``(B, H, W)`` array from ``(H, W)`` or ``(B, H, W)``; finite, at least 2 x 2."""
    a = _as_array(name, value)
    if a.ndim == 2 and batch in (None, 1):
        a = a[None]
    if a.ndim != 3 or (batch is not None and a.shape[0] != batch):
        want = "(H, W) or (B, H, W)" if batch is None else ("(H, W) or (1, H, W)" if batch == 1 else f"({batch}, H, W)")
        raise ValueError(f"{name}: shape {tuple(_as_array(name, value).shape)}; expected {want}")
    if a.shape[0] < 1 or a.shape[1] < 2 or a.shape[2] < 2:
        raise ValueError(f"{name}: shape {tuple(a.shape)}; needs at least 2 x 2 values per grid")
    a = np.ascontiguousarray(a, dtype=np.float32)
    if not np.isfinite(a).all():
        bad = int((~np.isfinite(a)).sum())
        raise ValueError(f"{name}: {bad} value(s) are NaN or infinite; heights must be finite")
    return a


def _check_positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r}: must be a number") from None
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name}={value!r}: must be a finite number > 0")
    return v


def _check_points(points, batch: int) -> list[np.ndarray]:
    """Per sample, the ``(N_b, 3)`` float32 points with NaN rows dropped."""
    a = _as_array("points", points)
    if a.ndim == 2 and batch == 1:
        a = a[None]
    if a.ndim != 3 or a.shape[0] != batch or a.shape[2] != 3:
        want = "(N, 3)" if batch == 1 else f"({batch}, N, 3)"
        raise ValueError(f"points: shape {tuple(_as_array('points', points).shape)}; expected {want}")
    a = a.astype(np.float32, copy=False)
    nan_rows = np.isnan(a).any(axis=2)
    if np.isinf(a[~nan_rows]).any():
        raise ValueError("points: infinite coordinates; use NaN rows for rays without a return")
    return [np.ascontiguousarray(a[b][~nan_rows[b]]) for b in range(batch)]


def _per_sample(name: str, value, batch: int) -> np.ndarray:
    a = _as_array(name, value).astype(np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, batch)
    if a.size != batch:
        raise ValueError(f"{name}: {a.size} values for {batch} samples; give one number or one per sample")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: must be finite")
    return a


# ------------------------------------------------------------------------------ geometry
def grid_points(heights: np.ndarray, cell: float) -> np.ndarray:
    """``(H*W, 3)`` float32 vertex positions of an ``(H, W)`` heightfield (row-major: i*W + j)."""
    H, W = heights.shape
    x = ((np.arange(H, dtype=np.float64) - 0.5 * (H - 1)) * cell).astype(np.float32)
    y = ((np.arange(W, dtype=np.float64) - 0.5 * (W - 1)) * cell).astype(np.float32)
    pts = np.empty((H, W, 3), dtype=np.float32)
    pts[..., 0] = x[:, None]
    pts[..., 1] = y[None, :]
    pts[..., 2] = heights
    return pts.reshape(-1, 3)


def grid_faces(H: int, W: int) -> np.ndarray:
    """``(2*(H-1)*(W-1), 3)`` int32 triangles: per cell ``(i,j),(i+1,j),(i+1,j+1)`` then
    ``(i,j),(i+1,j+1),(i,j+1)`` (the simulator's diagonal), counter-clockwise from +z."""
    if H * W >= 2**31:
        raise ValueError(f"heights: {H} x {W} vertices exceed USD's 32-bit face indices")
    v00 = (np.arange(H - 1, dtype=np.int32)[:, None] * W + np.arange(W - 1, dtype=np.int32)[None, :]).reshape(-1)
    v10 = v00 + W
    v11 = v10 + 1
    v01 = v00 + 1
    faces = np.empty((v00.size, 2, 3), dtype=np.int32)
    faces[:, 0, 0], faces[:, 0, 1], faces[:, 0, 2] = v00, v10, v11
    faces[:, 1, 0], faces[:, 1, 1], faces[:, 1, 2] = v00, v11, v01
    return faces.reshape(-1, 3)


def grid_normals(heights: np.ndarray, cell: float) -> np.ndarray:
    """``(H*W, 3)`` float32 unit vertex normals (central differences; one-sided at the border),
    all with positive z."""
    h = heights.astype(np.float32, copy=False)
    dzdx, dzdy = np.gradient(h, np.float32(cell))
    n = np.empty(h.shape + (3,), dtype=np.float32)
    n[..., 0] = -dzdx
    n[..., 1] = -dzdy
    n[..., 2] = 1.0
    n /= np.sqrt(np.einsum("...k,...k->...", n, n))[..., None]
    return n.reshape(-1, 3)


def _colors(values: np.ndarray, vmin: float, vmax: float, cmap: str) -> np.ndarray:
    """``(N, 3)`` float32 RGB of ``values`` on ``cmap`` over ``[vmin, vmax]`` (a 256-entry lookup)."""

    try:
        lut = matplotlib.colormaps[cmap](np.linspace(0.0, 1.0, 256))[:, :3].astype(np.float32)
    except KeyError:
        raise ValueError(f"cmap={cmap!r}: not a matplotlib colormap") from None
    span = vmax - vmin if vmax - vmin > 1e-9 else 1.0
    idx = np.clip((values.reshape(-1).astype(np.float32) - np.float32(vmin)) * np.float32(255.0 / span) + np.float32(0.5), 0, 255)
    return lut[idx.astype(np.uint8)]


# ------------------------------------------------------------------------------ stage
def _vec3f(a: np.ndarray):

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _extent(pts: np.ndarray):

    if len(pts) == 0:
        return Vt.Vec3fArray.FromNumpy(np.zeros((2, 3), dtype=np.float32))
    return Vt.Vec3fArray.FromNumpy(np.stack([pts.min(axis=0), pts.max(axis=0)]).astype(np.float32))


def _new_stage(path: Path, documentation: str):
    """``(stage, /World)``: an in-memory stage for ``path``'s format, Z up, metres, documented."""
    stage = Usd.Stage.CreateInMemory(f"anon{path.suffix}")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = _xform(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    stage.GetRootLayer().documentation = documentation
    return stage, world


def _xform(stage, path: str, translate=(0.0, 0.0, 0.0)):

    xf = UsdGeom.Xform.Define(stage, path)
    if any(float(t) != 0.0 for t in translate):
        xf.AddTranslateOp().Set(Gf.Vec3d(*(float(t) for t in translate)))
    return xf


def _grid_mesh(stage, path: str, heights: np.ndarray, cell: float, colors: np.ndarray, doc: str):

    H, W = heights.shape
    pts = grid_points(heights, cell)
    faces = grid_faces(H, W)
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(_vec3f(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(faces.shape[0], 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDoubleSidedAttr(False)
    mesh.CreateNormalsAttr(_vec3f(grid_normals(heights, cell)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateExtentAttr(_extent(pts))
    color = mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
    color.Set(_vec3f(colors))
    prim = mesh.GetPrim()
    prim.SetDocumentation(doc)
    prim.CreateAttribute("warpTerrain:cell", Sdf.ValueTypeNames.Double, custom=True).Set(float(cell))
    prim.CreateAttribute("warpTerrain:gridShape", Sdf.ValueTypeNames.Int2, custom=True).Set(Gf.Vec2i(int(H), int(W)))
    return mesh


def _points_prim(stage, path: str, pts: np.ndarray, width: float, colors: np.ndarray):

    prim = UsdGeom.Points.Define(stage, path)
    prim.CreatePointsAttr(_vec3f(pts.reshape(-1, 3)))
    prim.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.full(1, width, dtype=np.float32)))
    prim.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    half = np.float32(0.5 * width) if len(pts) else np.float32(0.0)
    prim.CreateExtentAttr(_extent(pts.reshape(-1, 3)) if not len(pts) else _vec3f(np.stack([pts.min(axis=0) - half, pts.max(axis=0) + half])))
    prim.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(_vec3f(colors.reshape(-1, 3)))
    prim.GetPrim().SetDocumentation("LIDAR returns in the sensor frame (metres; rays without a return dropped)")
    return prim


def export_usd(
    path,
    heights,
    cell,
    points=None,
    reconstruction=None,
    *,
    reconstruction_cell=None,
    target=None,
    sensor_z=0.0,
    cmap: str = "viridis",
    error_cmap: str = "magma",
    point_width: float = 0.05,
    gap: float | None = None,
) -> Path:
    """Write a USD stage (``.usda`` or ``.usdc`` by ``path``'s suffix) of a terrain and, optionally,
    its LIDAR scan and a reconstructed elevation map; returns the written path.

    - ``heights``: ``(H, W)`` heightfield in metres (numpy array or torch tensor), vertex spacing
      ``cell`` metres, or ``(B, H, W)`` for a batch (one prim per sample, see the module doc).
    - ``points``: ``(N, 3)`` (``(B, N, 3)`` for a batch) LIDAR points in the sensor frame; NaN
      rows (rays without a return) are dropped. Written as ``UsdGeom.Points`` of constant width
      ``point_width`` metres, coloured by height.
    - ``reconstruction``: ``(S, S)`` (or ``(B, S, S)``) elevation map in the sensor frame with
      cells of ``reconstruction_cell`` metres (default ``cell``), written as a second mesh
      beside the terrain (translated ``+x`` by the terrain's width plus ``gap``).
    - ``target``: the ground-truth map for ``reconstruction`` (same shape; needs
      ``reconstruction``): adds a third mesh, the reconstruction coloured by
      ``|reconstruction - target|`` on ``error_cmap`` (0 to the sample's largest error), with the
      per-vertex error also stored as the primvar ``primvars:error``.
    - ``sensor_z``: the sensor frame's origin height in the terrain's frame (one number, or one
      per sample; ``Batch.sensor_z``): points and maps are placed under Xforms translated by it,
      their own coordinates staying sensor-frame values. The sensor is above the heightfield's
      centre (as ``cast_scans`` places it), so only z is needed.
    - ``cmap``: matplotlib colormap of height (one scale per sample, over terrain, points and map).
    - ``gap``: metres between the meshes of one sample and between samples (default: 5% of the
      terrain's width, at least 1 m).

    Raises ``ValueError`` (before any work) for a bad suffix, a missing or read-only folder,
    bad shapes, non-finite heights or a non-positive cell; on failure no file is left behind.
    """
    path = check_usd_path(path)
    cell = _check_positive("cell", cell)
    h = _check_grid("heights", heights, None)
    batch, H, W = h.shape
    single = _as_array("heights", heights).ndim == 2
    rec_cell = cell if reconstruction_cell is None else _check_positive("reconstruction_cell", reconstruction_cell)
    rec = None if reconstruction is None else _check_grid("reconstruction", reconstruction, batch)
    if target is not None:
        if rec is None:
            raise ValueError("target: given without a reconstruction; it is the ground truth the reconstruction's error is measured against")
        tgt = _check_grid("target", target, batch)
        if tgt.shape != rec.shape:
            raise ValueError(f"target: shape {tuple(tgt.shape)} differs from the reconstruction's {tuple(rec.shape)}")
    else:
        tgt = None
    pts = None if points is None else _check_points(points, batch)
    sz = _per_sample("sensor_z", sensor_z, batch)
    width = _check_positive("point_width", point_width)
    gap = max(1.0, 0.05 * (H - 1) * cell) if gap is None else float(gap)
    if not math.isfinite(gap) or gap < 0:
        raise ValueError(f"gap={gap!r}: must be a finite number >= 0")

    for name, value in (("cmap", cmap), ("error_cmap", error_cmap)):
        if value not in matplotlib.colormaps:
            raise ValueError(f"{name}={value!r}: not a matplotlib colormap")


    stage, world = _new_stage(path, "warp-terrain export: terrain mesh (world frame), LIDAR points and reconstructed maps "
                              "(sensor frame, placed by the Sensor/Reconstruction Xforms); metres, Z up")

    terrain_x = (H - 1) * cell
    terrain_y = (W - 1) * cell
    rec_x = 0.0 if rec is None else (rec.shape[1] - 1) * rec_cell
    rec_y = 0.0 if rec is None else (rec.shape[2] - 1) * rec_cell
    pitch_y = max(terrain_y, rec_y) + gap
    rec_dx = 0.5 * terrain_x + gap + 0.5 * rec_x
    err_dx = rec_dx + rec_x + gap
    for b in range(batch):
        root = "/World" if single else f"/World/Sample_{b:04d}"
        if not single:
            _xform(stage, root, (0.0, b * pitch_y, 0.0))
        # one colour scale per sample, in the terrain's frame
        lo, hi = float(h[b].min()), float(h[b].max())
        if rec is not None:
            lo, hi = min(lo, float(rec[b].min()) + sz[b]), max(hi, float(rec[b].max()) + sz[b])
        terrain = _grid_mesh(stage, f"{root}/Terrain", h[b], cell, _colors(h[b], lo, hi, cmap),
                             "terrain heightfield, world frame (metres); vertex (i, j) at ((i-(H-1)/2)*cell, (j-(W-1)/2)*cell, h[i, j])")
        terrain.GetPrim().CreateAttribute("warpTerrain:sensorZ", Sdf.ValueTypeNames.Double, custom=True).Set(float(sz[b]))
        if pts is not None:
            _xform(stage, f"{root}/Sensor", (0.0, 0.0, sz[b]))
            p = pts[b]
            _points_prim(stage, f"{root}/Sensor/LidarPoints", p, width, _colors(p[:, 2] + np.float32(sz[b]), lo, hi, cmap))
        if rec is not None:
            _xform(stage, f"{root}/Reconstruction", (rec_dx, 0.0, sz[b]))
            _grid_mesh(stage, f"{root}/Reconstruction/Map", rec[b], rec_cell, _colors(rec[b] + np.float32(sz[b]), lo, hi, cmap),
                       "reconstructed elevation map, sensor frame (metres)")
        if tgt is not None:
            err = np.abs(rec[b] - tgt[b])
            _xform(stage, f"{root}/ReconstructionError", (err_dx, 0.0, sz[b]))
            mesh = _grid_mesh(stage, f"{root}/ReconstructionError/Map", rec[b], rec_cell, _colors(err, 0.0, float(err.max()), error_cmap),
                              "reconstructed elevation map coloured by |reconstruction - target| (primvars:error, metres)")

            pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("error", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
            pv.Set(Vt.FloatArray.FromNumpy(err.reshape(-1)))
            rmse = float(np.sqrt(np.mean(err.astype(np.float64) ** 2)))
            mesh.GetPrim().CreateAttribute("warpTerrain:rmse", Sdf.ValueTypeNames.Double, custom=True).Set(rmse)

    _write_atomically(stage, path)
    return path


def _write_atomically(stage, path: Path) -> None:

    try:
        with atomic_path(path) as tmp:
            try:
                ok = stage.GetRootLayer().Export(str(tmp))
            except Tf.ErrorException as err:
                raise ValueError(f"path={str(path)!r}: USD could not write the stage ({' '.join(str(err).split())[:300]})") from None
            if not ok:
                raise ValueError(f"path={str(path)!r}: USD could not write the stage")
    except ValueError as err:
        message = str(err)
        raise ValueError(message if message.startswith("path=") else f"path={message}") from None
    layer = Sdf.Layer.Find(str(path))  # a stage of the old file open in this process: show the new one
    if layer is not None:
        layer.Reload(True)


def export_reconstruction(path, height, cell, points=None, *, mask=None, uncertainty=None, cmap: str = "viridis",
                          point_width: float = 0.05) -> Path:
    """Write a USD stage (``.usda``/``.usdc``) of a map reconstructed from a real cloud (no
    terrain to show beside it); returns the written path. The stage is the sensor frame itself
    (metres, Z up; ``/World`` at the LIDAR)::

        /World
          Sensor/LidarPoints      Points: ``points`` (N, 3), sensor frame, those over the map only
          Reconstruction/Map      Mesh: ``height`` (S, S), vertex (i, j) at the centre of map cell
                                  (i, j), z = height[i, j]; primvars ``observed`` (the mask, 0/1)
                                  and ``uncertainty`` (sigma, m) when given

    Points and mesh share one height colour scale (``cmap``); points outside the map's square
    are left out (a georeferenced tile can hold millions of them far from the sensor).
    Raises ``ValueError`` before any work for a bad path, shapes, non-finite heights or cell."""
    path = check_usd_path(path)
    cell = _check_positive("cell", cell)
    h = _check_grid("height", height, 1)[0]
    extras = {}
    for name, primvar, value in (("mask", "observed", mask), ("uncertainty", "uncertainty", uncertainty)):
        if value is not None:
            if name == "mask" and isinstance(value, np.ndarray) and value.dtype == bool:
                value = value.astype(np.float32)
            a = _as_array(name, value).astype(np.float32)
            if a.shape != h.shape:
                raise ValueError(f"{name}: shape {a.shape} is not the map's {h.shape}")
            extras[primvar] = np.ascontiguousarray(a)
    pts = None
    if points is not None:
        pts = _check_points(points, 1)[0]
        half = np.float32(0.5 * h.shape[0] * cell), np.float32(0.5 * h.shape[1] * cell)
        pts = pts[(np.abs(pts[:, 0]) <= half[0]) & (np.abs(pts[:, 1]) <= half[1])]
    width = _check_positive("point_width", point_width)
    if cmap not in matplotlib.colormaps:
        raise ValueError(f"cmap={cmap!r}: not a matplotlib colormap")

    stage, world = _new_stage(path, "warp-terrain reconstruct: a reconstructed elevation map and the LIDAR points "
                              "it was made from, both in the sensor frame; metres, Z up")
    lo, hi = float(h.min()), float(h.max())
    if pts is not None:
        _xform(stage, "/World/Sensor")
        _points_prim(stage, "/World/Sensor/LidarPoints", pts, width, _colors(pts[:, 2], lo, hi, cmap))
    _xform(stage, "/World/Reconstruction")
    mesh = _grid_mesh(stage, "/World/Reconstruction/Map", h, cell, _colors(h, lo, hi, cmap),
                      "reconstructed elevation map, sensor frame (metres); vertex (i, j) at the centre of map cell (i, j)")
    for name, a in extras.items():
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
        pv.Set(Vt.FloatArray.FromNumpy(a.reshape(-1)))
    _write_atomically(stage, path)
    return path
