"""The 3-D scene of ``warp-terrain view`` as plain numpy: meshes, colours and named nodes.

Nothing here knows the web viewer (``plots.viewer`` hands these nodes to viser), so every
vertex, face and colour can be checked without a browser.

A map of ``S x S`` cells becomes a surface of ``S*S`` vertices, one per cell centre: vertex
``p*S + q`` lies at ``(c[p], c[q], height[p, q])`` with ``c = MapGeometry.centres()`` (the
sensor frame, metres), and ``2*(S-1)**2`` triangles, per cell ``(p,q),(p+1,q),(p+1,q+1)`` and
``(p,q),(p+1,q+1),(p,q+1)`` (the simulator's diagonal), counter-clockwise seen from +z. The
scan image is drawn as one flat square per observed cell (4 vertices, 2 triangles each).

The scene has up to three panels side by side along x, each the map in the sensor frame
shifted by its panel offset: ``input`` (the scan image and the LIDAR points; for a map file,
its observed cells), ``prediction`` (the model's map, or the file's) and ``truth`` (the ground
truth the model is scored against: the true surface averaged over each map cell). Its nodes
are named ``NODE_NAMES``; ``LAYERS`` says which nodes each GUI toggle shows or hides.
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import torch

from ..core.geometry import MapGeometry
from ..inference.predictor import Predictor
from ..sim import SimConfig, generate_batch, resolve_device
from ..sim.batch import unaugmented

#: colour maps: heights, and the per-cell sigma / error (as in the reconstruct PNG)
HEIGHT_CMAP = "viridis"
SPREAD_CMAP = "magma"
#: RGB of a value that is NaN (no uncertainty there), and of the LIDAR points
NAN_RGB = (128, 128, 128)
POINT_RGB = (230, 57, 40)
#: the GUI's colouring choices, in the order the dropdown lists them (those a sample has)
COLOR_MODES = ("height", "uncertainty", "error")
#: panels left to right (x), and each one's title
PANELS = ("input", "prediction", "truth")
#: GUI toggle -> the scene nodes it shows or hides
LAYERS = {
    "truth": ("/truth/surface",),
    "prediction": ("/prediction/surface",),
    "points": ("/input/points",),
    "scan": ("/input/scan",),
}
#: every node a scene can hold: the layers' nodes and one label per panel
NODE_NAMES = (*(name for names in LAYERS.values() for name in names), *(f"/{panel}/label" for panel in PANELS))
PANEL_GAP = 0.1  #: space between panels, as a fraction of the map's extent


# ------------------------------------------------------------------------------ meshes
@dataclass(frozen=True)
class SurfaceMesh:
    """A triangle mesh: ``vertices`` float32 ``(V, 3)``, ``faces`` uint32 ``(F, 3)`` and
    per-vertex ``colors`` uint8 ``(V, 3)`` (sRGB)."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray


def colormap_rgb(values, vmin: float, vmax: float, cmap: str = HEIGHT_CMAP) -> np.ndarray:
    """uint8 ``(..., 3)`` sRGB of ``values`` on matplotlib's ``cmap`` over ``[vmin, vmax]``
    (clipped; a span under 1e-9 m counts as 1 m); NaN gives ``NAN_RGB``."""
    try:
        lut = matplotlib.colormaps[cmap]
    except KeyError:
        raise ValueError(f"cmap={cmap!r}: not a matplotlib colormap") from None
    v = np.asarray(values, dtype=np.float64)
    span = vmax - vmin if vmax - vmin > 1e-9 else 1.0
    t = np.clip((v - vmin) / span, 0.0, 1.0)
    rgb = np.asarray(lut(np.where(np.isnan(t), 0.0, t).reshape(-1), bytes=True))[:, :3].copy()
    rgb[np.isnan(v).reshape(-1)] = NAN_RGB
    return rgb.reshape(v.shape + (3,))


def _check_grid(name: str, value, geometry: MapGeometry) -> np.ndarray:
    a = np.asarray(value)
    if a.shape != (geometry.size, geometry.size):
        raise ValueError(f"{name}: shape {a.shape} is not the map's {(geometry.size, geometry.size)}")
    return a


def surface_faces(size: int) -> np.ndarray:
    """``(2*(size-1)**2, 3)`` uint32 triangles of a ``size x size`` vertex grid (row-major, see the module doc)."""
    if size < 2:
        raise ValueError(f"size={size}: a surface needs at least 2 x 2 cells")
    p = np.arange(size - 1, dtype=np.uint32)
    v00 = (p[:, None] * np.uint32(size) + p[None, :]).reshape(-1)
    v10, v01 = v00 + np.uint32(size), v00 + np.uint32(1)
    v11 = v10 + np.uint32(1)
    return np.stack([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)], 1).reshape(-1, 3)


def surface_mesh(height, geometry: MapGeometry, colors) -> SurfaceMesh:
    """The map ``height`` ``(S, S)`` as a surface over the cell centres of ``geometry``, with
    per-cell ``colors`` ``(S, S, 3)`` uint8 (from :func:`colormap_rgb`)."""
    h = _check_grid("height", height, geometry).astype(np.float32)
    if not np.isfinite(h).all():
        raise ValueError("height: has NaN or infinite values; a surface needs a height in every cell")
    colors = np.asarray(colors, dtype=np.uint8)
    if colors.shape != h.shape + (3,):
        raise ValueError(f"colors: shape {colors.shape} is not {h.shape + (3,)}")
    S = geometry.size
    c = geometry.centres().astype(np.float32)
    vertices = np.empty((S, S, 3), dtype=np.float32)
    vertices[..., 0] = c[:, None]
    vertices[..., 1] = c[None, :]
    vertices[..., 2] = h
    return SurfaceMesh(vertices.reshape(-1, 3), surface_faces(S), colors.reshape(-1, 3).copy())


def tiles_mesh(values, mask, geometry: MapGeometry, colors) -> SurfaceMesh:
    """One flat square per cell where ``mask`` is set, at that cell's value: the scan image in
    3-D. Cell ``k`` (in row-major order of the set cells) has vertices ``4k .. 4k+3`` at its
    corners ``(x-, y-), (x+, y-), (x+, y+), (x-, y+)`` and triangles ``(0,1,2), (0,2,3)`` of
    them, counter-clockwise from +z."""
    m = _check_grid("mask", mask, geometry).astype(bool)
    v = _check_grid("values", values, geometry).astype(np.float32)
    colors = np.asarray(colors, dtype=np.uint8)
    if colors.shape != v.shape + (3,):
        raise ValueError(f"colors: shape {colors.shape} is not {v.shape + (3,)}")
    p, q = np.nonzero(m)
    if not np.isfinite(v[p, q]).all():
        raise ValueError("values: NaN or infinite values in observed cells")
    c = geometry.centres()
    half = 0.5 * geometry.cell
    dx = np.array([-half, half, half, -half])
    dy = np.array([-half, -half, half, half])
    vertices = np.empty((p.size, 4, 3), dtype=np.float32)
    vertices[..., 0] = c[p][:, None] + dx
    vertices[..., 1] = c[q][:, None] + dy
    vertices[..., 2] = v[p, q][:, None]
    base = (np.arange(p.size, dtype=np.uint32) * np.uint32(4))[:, None]
    faces = np.concatenate([base + np.array([0, 1, 2], np.uint32), base + np.array([0, 2, 3], np.uint32)], 1).reshape(-1, 3)
    return SurfaceMesh(vertices.reshape(-1, 3), faces, np.repeat(colors[p, q], 4, axis=0))


def vertex_normals(mesh: SurfaceMesh) -> np.ndarray:
    """float32 ``(V, 3)`` unit normals: the area-weighted mean of the faces around each vertex
    (+z for a vertex no face uses)."""
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces.astype(np.int64)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], face_n)
    length = np.linalg.norm(n, axis=1)
    n[length == 0] = (0.0, 0.0, 1.0)
    length[length == 0] = 1.0
    return (n / length[:, None]).astype(np.float32)


def srgb_to_linear(rgb) -> np.ndarray:
    """float32 linear-light RGB in [0, 1] from uint8 sRGB (glTF stores vertex colours linear)."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _pad4(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def mesh_glb(mesh: SurfaceMesh) -> bytes:
    """``mesh`` as a binary glTF 2.0 (GLB): one primitive with ``POSITION``, ``NORMAL``,
    ``COLOR_0`` (linear float RGB) and uint32 indices; a double-sided, non-metallic material
    that takes its colour from the vertices. Coordinates are kept as they are (z up)."""
    positions = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    arrays = [positions, vertex_normals(mesh), srgb_to_linear(mesh.colors),
              np.ascontiguousarray(mesh.faces, dtype=np.uint32).reshape(-1)]
    views, accessors, blob = [], [], b""
    for k, a in enumerate(arrays):
        data = a.tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data), "target": 34963 if k == 3 else 34962})
        blob += _pad4(data, b"\0")
        accessor = {"bufferView": k, "componentType": 5125 if k == 3 else 5126, "count": int(a.shape[0]),
                    "type": "SCALAR" if k == 3 else "VEC3"}
        if k == 0:
            accessor["min"] = [float(x) for x in positions.min(axis=0)] if len(positions) else [0.0, 0.0, 0.0]
            accessor["max"] = [float(x) for x in positions.max(axis=0)] if len(positions) else [0.0, 0.0, 0.0]
        accessors.append(accessor)
    doc = {
        "asset": {"version": "2.0", "generator": "warp-terrain"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "COLOR_0": 2}, "indices": 3, "mode": 4, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.9},
                       "doubleSided": True}],
        "buffers": [{"byteLength": len(blob)}], "bufferViews": views, "accessors": accessors,
    }
    text = _pad4(json.dumps(doc, separators=(",", ":")).encode(), b" ")
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(text), b"JSON") + text
            + struct.pack("<I4s", len(blob), b"BIN\0") + blob)


# ------------------------------------------------------------------------------ samples
@dataclass(frozen=True)
class ViewSample:
    """What one view shows, every map ``(S, S)`` in the sensor frame of ``geometry``:
    ``prediction`` (the model's heights or a map file's), ``truth`` (the ground truth),
    ``scan`` and ``mask`` (the input image: heights of the observed cells, and which they are),
    ``uncertainty`` (sigma per cell, m), ``points`` ``(N, 3)`` (the LIDAR returns); any may be
    None. ``title`` names it in the GUI."""

    geometry: MapGeometry
    prediction: np.ndarray | None = None
    truth: np.ndarray | None = None
    scan: np.ndarray | None = None
    mask: np.ndarray | None = None
    uncertainty: np.ndarray | None = None
    points: np.ndarray | None = None
    title: str = ""

    def __post_init__(self):
        for name in ("prediction", "truth", "scan", "mask", "uncertainty"):
            value = getattr(self, name)
            if value is not None:
                _check_grid(name, value, self.geometry)
        for name in ("prediction", "truth"):
            value = getattr(self, name)
            if value is not None and not np.isfinite(value).all():
                raise ValueError(f"{name}: has NaN or infinite heights")
        if (self.scan is None) != (self.mask is None):
            raise ValueError("scan and mask: give both or neither")
        if self.uncertainty is not None and self.prediction is None:
            raise ValueError("uncertainty: needs the prediction it belongs to")
        if self.points is not None:
            pts = np.asarray(self.points)
            if pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
                raise ValueError(f"points: expected a finite (N, 3) array, got shape {pts.shape}")
        if self.panels() == ():
            raise ValueError("a view needs a prediction, a truth or a scan")

    def panels(self) -> tuple[str, ...]:
        """The panels this sample fills, left to right."""
        present = {"input": self.scan is not None or self.points is not None,
                   "prediction": self.prediction is not None, "truth": self.truth is not None}
        return tuple(p for p in PANELS if present[p])

    def layers(self) -> tuple[str, ...]:
        """The ``LAYERS`` this sample has."""
        present = {"truth": self.truth is not None, "prediction": self.prediction is not None,
                   "points": self.points is not None, "scan": self.scan is not None}
        return tuple(layer for layer in LAYERS if present[layer])

    def color_modes(self) -> tuple[str, ...]:
        """The colourings it offers: height always, uncertainty with a sigma, error with a truth."""
        ok = {"height": True, "uncertainty": self.uncertainty is not None,
              "error": self.prediction is not None and self.truth is not None}
        return tuple(mode for mode in COLOR_MODES if ok[mode])


def simulated_samples(sim: SimConfig, seed: int = 0, count: int = 1, predictor: Predictor | None = None,
                      device=None) -> list[ViewSample]:
    """Samples ``0 .. count-1`` of ``generate_batch(count, sim, seed)`` (augmentation and domain
    randomisation off, on a copy) as views: the scan image, mask, LIDAR returns (no-return rows
    dropped) and ground truth, plus ``predictor``'s map (and sigma) when given."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed={seed!r}: must be an integer")
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise ValueError(f"count={count!r}: must be an integer >= 1")
    sim = unaugmented(sim)
    device = resolve_device(device)
    batch = generate_batch(int(count), sim, seed=int(seed), device=device)
    prediction = sigma = None
    if predictor is not None:
        with torch.no_grad():
            out = predictor(batch.scan, batch.mask)
        prediction, sigma = out if isinstance(out, tuple) else (out, None)
        prediction = prediction[:, 0].detach().float().cpu().numpy()
        sigma = None if sigma is None else sigma[:, 0].detach().float().cpu().numpy()
    geometry = MapGeometry(sim.data.map_size, sim.data.map_cell)
    scan = batch.scan[:, 0].cpu().numpy()
    mask = batch.mask[:, 0].cpu().numpy() > 0.5
    target = batch.target[:, 0].cpu().numpy()
    points = batch.points.cpu().numpy()
    samples = []
    for i in range(int(count)):
        pts = points[i][np.isfinite(points[i]).all(axis=1)]
        samples.append(ViewSample(geometry, prediction=None if prediction is None else prediction[i], truth=target[i],
                                  scan=np.where(mask[i], scan[i], 0.0).astype(np.float32), mask=mask[i],
                                  uncertainty=None if sigma is None else sigma[i], points=pts,
                                  title=f"{sim.terrain.name}, seed {seed}, sample {i}"))
    return samples


def load_map_file(path: str | os.PathLike) -> ViewSample:
    """A map written by ``warp-terrain reconstruct`` (``.npz``: ``height``, ``mask``,
    ``map_cell``, optional ``uncertainty``) as a view: ``prediction`` its heights, ``scan`` and
    ``mask`` its observed cells. A missing or unreadable file, a missing array, shapes that are
    not one ``(S, S)`` map, a bad ``map_cell`` or non-finite heights raise ValueError naming it."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise ValueError(f"{str(path)!r}: view reads .npz maps (warp-terrain reconstruct --out MAP.npz)")
    if not path.is_file():
        raise ValueError(f"{str(path)!r}: no such file")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {key: np.asarray(npz[key]) for key in npz.files}
    except Exception as err:  # noqa: BLE001  (zipfile, pickle and format errors alike)
        raise ValueError(f"{str(path)!r}: not a readable .npz ({type(err).__name__})") from None
    missing = [key for key in ("height", "mask", "map_cell") if key not in arrays]
    if missing:
        raise ValueError(f"{str(path)!r}: missing {', '.join(missing)} (not a map written by warp-terrain reconstruct)")
    height = arrays["height"]
    if height.ndim != 2 or height.shape[0] != height.shape[1] or height.shape[0] < 2:
        raise ValueError(f"{str(path)!r}: height has shape {height.shape}, expected one (S, S) map with S >= 2")
    cell = arrays["map_cell"]
    ok = cell.shape == () and (np.issubdtype(cell.dtype, np.floating) or np.issubdtype(cell.dtype, np.integer))
    if not ok or not np.isfinite(cell) or float(cell) <= 0:
        raise ValueError(f"{str(path)!r}: map_cell={cell!r} is not a positive cell size in metres")
    geometry = MapGeometry(int(height.shape[0]), float(cell))
    for key in ("height", "mask", "uncertainty"):
        if key in arrays and arrays[key].shape != height.shape:
            raise ValueError(f"{str(path)!r}: {key} has shape {arrays[key].shape}, height {height.shape}")
        if key in arrays and not (np.issubdtype(arrays[key].dtype, np.number) or arrays[key].dtype == bool):
            raise ValueError(f"{str(path)!r}: {key} holds {arrays[key].dtype}, not numbers")
    if not np.isfinite(height).all():
        raise ValueError(f"{str(path)!r}: height has NaN or infinite values")
    mask = arrays["mask"] > 0.5
    height = height.astype(np.float32)
    return ViewSample(geometry, prediction=height, scan=np.where(mask, height, 0.0).astype(np.float32), mask=mask,
                      uncertainty=arrays["uncertainty"].astype(np.float32) if "uncertainty" in arrays else None,
                      title=path.name)


# ------------------------------------------------------------------------------ scene
@dataclass(frozen=True)
class MeshNode:
    mesh: SurfaceMesh
    position: tuple[float, float, float]


@dataclass(frozen=True)
class PointsNode:
    points: np.ndarray  # float32 (N, 3)
    color: tuple[int, int, int]
    size: float
    position: tuple[float, float, float]


@dataclass(frozen=True)
class LabelNode:
    text: str
    position: tuple[float, float, float]


@dataclass(frozen=True)
class Scene:
    """Named nodes (names from ``NODE_NAMES``), each in its panel's frame at ``position``; the
    ``legend`` (Markdown: what the colours mean); a camera ``eye`` and ``target`` that see it all."""

    nodes: dict
    legend: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]


def panel_offsets(sample: ViewSample) -> dict[str, float]:
    """x offset of each panel's centre: side by side, ``PANEL_GAP`` of the extent apart, centred on 0."""
    panels = sample.panels()
    pitch = sample.geometry.extent * (1.0 + PANEL_GAP)
    return {panel: (k - 0.5 * (len(panels) - 1)) * pitch for k, panel in enumerate(panels)}


def height_range(sample: ViewSample) -> tuple[float, float]:
    """The one height scale of a view: min and max over prediction, truth and observed scan cells."""
    parts = [np.asarray(a, dtype=np.float64).reshape(-1) for a in (sample.prediction, sample.truth) if a is not None]
    if sample.scan is not None:
        parts.append(np.asarray(sample.scan, dtype=np.float64)[np.asarray(sample.mask, bool)])
    values = np.concatenate(parts) if parts else np.zeros(1)
    values = values if values.size else np.zeros(1)
    return float(values.min()), float(values.max())


def _spread_range(values) -> tuple[float, float]:
    finite = np.asarray(values, dtype=np.float64)[np.isfinite(values)]
    return 0.0, float(finite.max()) if finite.size else 1.0


def build_scene(sample: ViewSample, color_by: str = "height") -> Scene:
    """The nodes of ``sample`` coloured ``color_by`` (one of ``sample.color_modes()``): every
    surface and the scan by height on one ``HEIGHT_CMAP`` scale, except that ``uncertainty``
    colours the prediction by its sigma and ``error`` by ``|prediction - truth|`` (``SPREAD_CMAP``,
    from 0 to the largest value)."""
    if color_by not in sample.color_modes():
        raise ValueError(f"color_by={color_by!r}: this view offers {', '.join(sample.color_modes())}")
    g = sample.geometry
    vmin, vmax = height_range(sample)
    offsets = panel_offsets(sample)
    top = vmax + 0.05 * g.extent
    nodes = {}
    legend = [f"**height**: {HEIGHT_CMAP}, {vmin:.2f} m (dark) to {vmax:.2f} m (yellow)"]

    def at(panel: str) -> tuple[float, float, float]:
        return (float(offsets[panel]), 0.0, 0.0)

    if sample.truth is not None:
        nodes["/truth/surface"] = MeshNode(surface_mesh(sample.truth, g, colormap_rgb(sample.truth, vmin, vmax)), at("truth"))
        nodes["/truth/label"] = LabelNode("ground truth", (float(offsets["truth"]), g.half_extent, top))
    if sample.prediction is not None:
        if color_by == "height":
            colors = colormap_rgb(sample.prediction, vmin, vmax)
        else:
            spread = sample.uncertainty if color_by == "uncertainty" else np.abs(sample.prediction - sample.truth)
            lo, hi = _spread_range(spread)
            colors = colormap_rgb(spread, lo, hi, SPREAD_CMAP)
            what = "uncertainty (sigma)" if color_by == "uncertainty" else "error |prediction - truth|"
            legend.append(f"**prediction, {what}**: {SPREAD_CMAP}, {lo:.2f} m (black) to {hi:.2f} m (light)")
        nodes["/prediction/surface"] = MeshNode(surface_mesh(sample.prediction, g, colors), at("prediction"))
        title = "reconstruction" if sample.truth is not None or sample.points is not None else "map"
        nodes["/prediction/label"] = LabelNode(title, (float(offsets["prediction"]), g.half_extent, top))
    if sample.scan is not None:
        nodes["/input/scan"] = MeshNode(tiles_mesh(sample.scan, sample.mask, g, colormap_rgb(sample.scan, vmin, vmax)), at("input"))
    if sample.points is not None:
        nodes["/input/points"] = PointsNode(np.asarray(sample.points, dtype=np.float32), POINT_RGB, 0.4 * g.cell, at("input"))
    if "input" in offsets:
        text = "input: scan image + LIDAR points" if sample.points is not None else "observed cells"
        nodes["/input/label"] = LabelNode(text, (float(offsets["input"]), g.half_extent, top))
    if sample.points is not None:
        legend.append("**LIDAR points**: red")
    width = g.extent * (len(offsets) + PANEL_GAP * (len(offsets) - 1))
    zmid = 0.5 * (vmin + vmax)
    eye = (0.0, -0.75 * width - g.half_extent, zmid + 0.45 * width)
    return Scene(nodes, "  \n".join(legend), eye, (0.0, 0.0, zmid))
