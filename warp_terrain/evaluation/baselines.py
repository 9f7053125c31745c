"""Classical fills of elevation maps from the observed cells (the baselines a model must beat).

Every fill is a predictor ``f(scan, mask) -> prediction``: ``scan`` and ``mask`` are
``(B, 1, H, W)`` tensors (heights in metres, mask > 0 where the LIDAR saw the cell) and the
prediction is a ``(B, 1, H, W)`` float32 tensor on the scan's device. The work is done by
maintained libraries, one map at a time on the CPU:

============  ============================================================================
``nearest``   ``scipy.ndimage.distance_transform_edt`` nearest-feature indices (Euclidean)
``linear``    ``scipy.interpolate.LinearNDInterpolator`` on the observed cell centres
              (Delaunay, piecewise linear); outside their convex hull: ``nearest``
``biharmonic`` ``skimage.restoration.inpaint_biharmonic`` (the full map, no downsampling:
              about 0.1 s per 121x121 map with 70 % of the cells unknown, fast enough)
``harmonic``  Laplace interpolation (the membrane: the discrete Laplace equation solved exactly on
              the unobserved cells, reflecting edges; ``scipy.sparse.linalg.spsolve``). No
              overshoot: strong on rough ground and on noisy scans, where the thin plate
              swings between neighbouring observations
``telea``     ``cv2.inpaint(..., cv2.INPAINT_TELEA)`` (fast marching, Telea 2004)
``ns``        ``cv2.inpaint(..., cv2.INPAINT_NS)`` (Navier-Stokes, Bertalmio et al. 2001)
``plane``     least-squares plane ``z = a x + b y + c`` through the observed cells
              (``scipy.linalg.lstsq``)
============  ============================================================================

Conventions shared by all fills:

- observed cells keep their measured height (these are fills: they only invent the unobserved
  cells), so every baseline scores the same on observed cells: the scan's own error there;
- a map with no observed cell comes back as zeros (there is nothing to fill from; zero is also
  the scan image's fill value); a fully observed map comes back as the scan;
- every fill runs one map at a time with single-threaded BLAS, so ``ms per map`` compares
  like with like;
- ``linear`` needs three observed cells not on one line and ``plane`` needs three; with fewer,
  both fall back to ``nearest`` (one or two cells: the nearest observed height).

OpenCV's inpainting on ``float32`` images (accepted since OpenCV 3.4/4.x for one channel) has
two defects that this module works around rather than hides:

1. Telea's update adds the normalised gradient ``(Jx + Jy) / |J|`` (up to +-1.41) and a
   rounding ``+0.5`` in *intensity units* (``modules/photo/src/inpaint.cpp``; OpenCV issue
   #25404): harmless on 0..255 images, but on heights in metres it adds up to ~1.9 m of
   speckle (measured: a constant map is "filled" with values +-1.4 m off). Navier-Stokes
   thresholds its gradient dot products at 0.01 intensity units, also tuned for 8-bit scales.
   So each map is mapped affinely onto ``0..65535`` over its observed height range (or 1 m if
   that is smaller, e.g. a flat map), *kept in float32* (no quantisation: float32 resolves
   0.004 units there), inpainted, and mapped back. Telea's defect then amounts to at most
   ~2 / 65535 of that range (0.1 mm on a 4 m range, 0.03 mm on a flat map); the affine round
   trip itself costs below 1e-6 m (observed cells are restored exactly).
2. Pixels in the image's first row and column are never inpainted (the fast-marching loop skips
   them; OpenCV issue #25389). Each map is padded with a one-cell unknown border and cropped.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import torch
from scipy import ndimage, sparse
from scipy.interpolate import LinearNDInterpolator
from scipy.linalg import lstsq
from scipy.sparse.linalg import spsolve
from scipy.spatial import QhullError
from skimage.restoration import inpaint_biharmonic
from threadpoolctl import threadpool_limits

__all__ = [
    "BASELINES",
    "INPAINT_RADIUS",
    "biharmonic_fill",
    "grid_laplacian",
    "harmonic_fill",
    "linear_fill",
    "navier_stokes_fill",
    "nearest_fill",
    "plane_fill",
    "telea_fill",
]

#: ``inpaintRadius`` for OpenCV's Telea and Navier-Stokes fills, in cells (OpenCV's examples use 3).
INPAINT_RADIUS = 3
#: The observed height range (at least ``CV_MIN_SPAN`` metres) is mapped onto ``0..CV_SCALE``
#: (float32) before ``cv2.inpaint``.
CV_SCALE = 65535.0
CV_MIN_SPAN = 1.0


# ------------------------------------------------------------------------------ plumbing
def _check(scan: torch.Tensor, mask: torch.Tensor) -> None:
    if scan.dim() != 4 or scan.shape[1] != 1:
        raise ValueError(f"scan: expected shape (B, 1, H, W), got {tuple(scan.shape)}")
    if mask.shape != scan.shape:
        raise ValueError(f"mask: shape {tuple(mask.shape)} must match scan {tuple(scan.shape)}")


def _per_map(fill2d: Callable[[np.ndarray, np.ndarray], np.ndarray]):
    """Lift a 2-D fill ``(z float64 (H, W), known bool (H, W)) -> (H, W)`` to a batched predictor.

    ``fill2d`` is only called on maps with at least one observed and one unobserved cell.
    Observed cells of the result are reset to the scan's values. BLAS runs single-threaded
    inside (``threadpoolctl``): scipy's Delaunay interpolation makes one tiny LAPACK call per
    triangle, and OpenBLAS's thread pool made that 10-100x slower on a busy 2-core machine.
    """

    def predictor(scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        _check(scan, mask)
        s = scan.detach().to("cpu", torch.float64).numpy()
        m = mask.detach().cpu().numpy() > 0
        out = np.zeros(s.shape, dtype=np.float32)
        with threadpool_limits(limits=1, user_api="blas"):
            for b in range(s.shape[0]):
                z, known = s[b, 0], m[b, 0]
                if not known.any():
                    continue
                if known.all():
                    out[b, 0] = z
                    continue
                filled = np.asarray(fill2d(z, known), dtype=np.float64)
                out[b, 0] = np.where(known, z, filled)
        return torch.from_numpy(out).to(scan.device)

    predictor.__name__ = fill2d.__name__.lstrip("_")
    predictor.__doc__ = fill2d.__doc__
    return predictor


def _nearest2d(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    _, (ii, jj) = ndimage.distance_transform_edt(~known, return_indices=True)
    return z[ii, jj]


# ------------------------------------------------------------------------------ the fills
def _nearest(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Each unobserved cell takes the height of the nearest observed cell (Euclidean, in cells;
    ``scipy.ndimage.distance_transform_edt``'s nearest-feature indices)."""
    return _nearest2d(z, known)


def _linear(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation over the Delaunay triangulation of the observed cell
    centres (``scipy.interpolate.LinearNDInterpolator``); nearest outside their convex hull."""
    nearest = _nearest2d(z, known)
    if known.sum() < 3:
        return nearest
    pts = np.argwhere(known).astype(np.float64)
    try:
        interp = LinearNDInterpolator(pts, z[known])
    except QhullError:  # all observed cells on one line: no triangle to interpolate in
        return nearest
    ii, jj = np.nonzero(~known)
    values = interp(np.stack([ii, jj], axis=1).astype(np.float64))
    out = nearest.copy()
    out[ii, jj] = np.where(np.isfinite(values), values, nearest[ii, jj])
    return out


def _biharmonic(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Biharmonic inpainting of the unobserved cells (``skimage.restoration.inpaint_biharmonic``)."""
    return inpaint_biharmonic(np.where(known, z, 0.0), ~known)


def grid_laplacian(h: int, w: int) -> sparse.csr_matrix:
    """The graph Laplacian ``D - A`` of an ``h x w`` grid's 4-neighbour graph (cells in C order):
    the 5-point Laplacian, negated, with reflecting (Neumann) edges; symmetric, rows sum to 0."""
    index = np.arange(h * w).reshape(h, w)
    pairs = [(index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])]
    a = np.concatenate([p.ravel() for p, _ in pairs])
    b = np.concatenate([q.ravel() for _, q in pairs])
    ones = np.ones(a.size)
    adjacency = sparse.coo_matrix((np.r_[ones, ones], (np.r_[a, b], np.r_[b, a])), shape=(h * w, h * w)).tocsr()
    return (sparse.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()


def _harmonic(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Laplace interpolation: each unobserved cell the mean of its grid neighbours, solved
    exactly (``L_FF u_F = -L_FK z_K`` with ``scipy.sparse.linalg.spsolve``). The grid is
    connected, so with one observed cell the free block is positive definite."""
    lap = grid_laplacian(*z.shape)
    free, kept = np.flatnonzero(~known), np.flatnonzero(known)
    rhs = -lap[free][:, kept] @ z.ravel()[kept]
    out = z.astype(np.float64).ravel().copy()
    out[free] = spsolve(lap[free][:, free].tocsc(), rhs)
    return out.reshape(z.shape)


def _cv2_inpaint(z: np.ndarray, known: np.ndarray, flags: int, radius: float) -> np.ndarray:
    lo = float(z[known].min())
    span = max(float(z[known].max()) - lo, CV_MIN_SPAN)
    scale = CV_SCALE / span
    img = np.where(known, (z - lo) * scale, 0.0).astype(np.float32)
    holes = (~known).astype(np.uint8)
    img = np.pad(img, 1)  # one unknown cell all round: OpenCV never fills row 0 / column 0
    holes = np.pad(holes, 1, constant_values=1)
    out = cv2.inpaint(img, holes, float(radius), flags)[1:-1, 1:-1]
    return out.astype(np.float64) / scale + lo


def _telea(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """OpenCV's fast-marching inpainting (Telea 2004; ``cv2.INPAINT_TELEA``)."""
    return _cv2_inpaint(z, known, cv2.INPAINT_TELEA, INPAINT_RADIUS)


def _navier_stokes(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """OpenCV's Navier-Stokes inpainting (Bertalmio et al. 2001; ``cv2.INPAINT_NS``)."""
    return _cv2_inpaint(z, known, cv2.INPAINT_NS, INPAINT_RADIUS)


def _plane(z: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The least-squares plane ``z = a i + b j + c`` through the observed cells
    (``scipy.linalg.lstsq``); nearest with fewer than three observed cells."""
    if known.sum() < 3:
        return _nearest2d(z, known)
    ii, jj = np.nonzero(known)
    a = np.stack([ii, jj, np.ones_like(ii)], axis=1).astype(np.float64)
    coef, *_ = lstsq(a, z[ii, jj])
    gi, gj = np.indices(z.shape, dtype=np.float64)
    return coef[0] * gi + coef[1] * gj + coef[2]


nearest_fill = _per_map(_nearest)
linear_fill = _per_map(_linear)
biharmonic_fill = _per_map(_biharmonic)
harmonic_fill = _per_map(_harmonic)
telea_fill = _per_map(_telea)
navier_stokes_fill = _per_map(_navier_stokes)
plane_fill = _per_map(_plane)

#: The classical fills by name, each a predictor ``f(scan, mask) -> prediction``.
BASELINES: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {
    "nearest": nearest_fill,
    "linear": linear_fill,
    "biharmonic": biharmonic_fill,
    "harmonic": harmonic_fill,
    "telea": telea_fill,
    "ns": navier_stokes_fill,
    "plane": plane_fill,
}
