"""A USD stage drawn with matplotlib: what ``export_usd`` wrote, as a picture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from pxr import Usd, UsdGeom

from .common import check_png_path, new_figure, save_figure


def usd_figure(path, max_points: int = 20000, elev: float = 38.0, azim: float = -62.0):
    """A matplotlib 3-D drawing of a stage written by ``export_usd``: every mesh's triangles as
    they are in the file (world transforms applied, faces coloured by their ``displayColor`` and
    shaded by their normal) and up to ``max_points`` of each point cloud (in red)."""

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise ValueError(f"path={str(path)!r}: cannot open the USD stage")
    cache = UsdGeom.XformCache()
    fig = new_figure((9.0, 6.0))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    ax.computed_zorder = False  # points drawn over the surfaces they lie on
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    light = np.array([-0.4, -0.5, 0.77])
    light /= np.linalg.norm(light)
    for prim in stage.Traverse():
        world = np.array(cache.GetLocalToWorldTransform(prim), dtype=np.float64)  # row-vector convention
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            pts = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
            pts = pts @ world[:3, :3] + world[3, :3]
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
            if not (counts == 3).all():
                raise ValueError(f"{prim.GetPath()}: only triangle meshes are drawn")
            tris = pts[np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)]
            colors = mesh.GetDisplayColorPrimvar().Get()
            rgb = np.full((len(tris), 3), 0.6) if colors is None else np.asarray(colors)[np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)].mean(axis=1)
            n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            shade = 0.45 + 0.55 * np.clip(n @ light, 0.0, 1.0)
            ax.add_collection3d(Poly3DCollection(tris, facecolors=np.clip(rgb * shade[:, None], 0, 1), linewidths=0, antialiased=False))
            lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
        elif prim.IsA(UsdGeom.Points):
            geom = UsdGeom.Points(prim)
            pts = np.asarray(geom.GetPointsAttr().Get(), dtype=np.float64).reshape(-1, 3)
            if len(pts) == 0:
                continue
            pts = pts @ world[:3, :3] + world[3, :3]
            step = max(1, len(pts) // max(1, int(max_points)))
            ax.scatter(pts[::step, 0], pts[::step, 1], pts[::step, 2], c="red", s=0.4, lw=0, depthshade=False, zorder=10)
    if not np.isfinite(lo).all():
        raise ValueError(f"path={str(path)!r}: the stage holds no mesh")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    span = hi - lo
    ax.set_box_aspect((span[0], span[1], max(span[2] * 2.0, 0.05 * max(span[0], span[1]))))  # z exaggerated 2x
    ax.view_init(elev=elev, azim=azim)

    ax.zaxis.set_major_locator(MaxNLocator(3))
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.set_zlabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(f"{Path(path).name}: USD meshes as stored, LIDAR points in red (z exaggerated 2x)", fontsize=10)
    return fig


def write_usd_figure(path, out, dpi: int = 80) -> Path:
    """Draw the stage at ``path`` (``usd_figure``) into the PNG ``out``, atomically."""
    out = check_png_path(out)
    return save_figure(usd_figure(path), out, dpi=int(dpi))
