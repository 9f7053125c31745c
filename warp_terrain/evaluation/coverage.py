"""What a family of maps looks like: relief, slope, obstacles and how much the LIDAR saw.

``map_statistics`` measures one stack of maps the same way for a synthetic setting and a real
family, so the training world's coverage can be read beside the real ground's
(``warp-terrain evaluate --real`` prints both):

- ``relief_m``: height range of the true surface across the map (median and 90th percentile
  over the maps), metres;
- ``slope_deg``: the map's overall tilt, the slope of its least-squares plane (median, 90th
  percentile), degrees;
- ``local_slope_deg``: the median slope between neighbouring cells, degrees;
- ``obstacle_share``: share of cells more than ``OBSTACLE_M`` away from the bare ground (when
  the bare ground is known), the obstacles' footprint;
- ``observed_share``: share of cells with at least one return.
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["OBSTACLE_M", "map_statistics", "statistics_markdown"]

OBSTACLE_M = 0.25  #: a cell this far (m) from the bare ground belongs to an obstacle


def _plane_slope_deg(z: np.ndarray, cell: float) -> float:
    n = z.shape[0]
    c = (np.arange(n) - 0.5 * (n - 1)) * cell
    x, y = np.meshgrid(c, c, indexing="ij")
    a = np.stack([x.ravel(), y.ravel(), np.ones(z.size)], axis=1)
    (gx, gy, _), *_ = np.linalg.lstsq(a, z.ravel().astype(np.float64), rcond=None)
    return math.degrees(math.atan(math.hypot(gx, gy)))


def map_statistics(target: torch.Tensor, mask: torch.Tensor, cell: float, ground: torch.Tensor | None = None) -> dict[str, float]:
    """Statistics of ``(N, 1, S, S)`` true maps ``target`` with observation masks ``mask``."""
    z = target[:, 0].double().cpu().numpy()
    relief = z.max(axis=(1, 2)) - z.min(axis=(1, 2))
    tilt = np.array([_plane_slope_deg(m, cell) for m in z])
    gy, gx = np.gradient(z, cell, axis=(1, 2))
    local = np.degrees(np.arctan(np.hypot(gx, gy)))
    out = {
        "maps": int(z.shape[0]),
        "relief_m_median": float(np.median(relief)),
        "relief_m_p90": float(np.percentile(relief, 90)),
        "slope_deg_median": float(np.median(tilt)),
        "slope_deg_p90": float(np.percentile(tilt, 90)),
        "local_slope_deg_median": float(np.median(local)),
        "observed_share": float((mask > 0).double().mean()),
    }
    if ground is not None:
        out["obstacle_share"] = float(((target - ground).abs() > OBSTACLE_M).double().mean())
    return out


def statistics_markdown(rows: list[tuple[str, dict]]) -> str:
    """``(family, statistics)`` rows as one Markdown table."""
    lines = ["| family | maps | relief (m) median / p90 | tilt (deg) median / p90 | local slope (deg) | obstacle cells | observed |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, s in rows:
        obstacles = f"{100 * s['obstacle_share']:.1f} %" if "obstacle_share" in s else "-"
        lines.append(f"| {name} | {s['maps']} | {s['relief_m_median']:.2f} / {s['relief_m_p90']:.2f} | {s['slope_deg_median']:.1f} / "
                     f"{s['slope_deg_p90']:.1f} | {s['local_slope_deg_median']:.1f} | {obstacles} | {100 * s['observed_share']:.0f} % |")
    return "\n".join(lines) + "\n"
