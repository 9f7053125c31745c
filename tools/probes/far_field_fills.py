"""Probe (README, "How far the synthetic targets can go"): fills that revert to a reference far
from the scan, and whether the scan can tell which one to use.

The candidates minimise ``|L v|^2 + 2 k^2 |grad v|^2 + k^4 |v|^2`` over the unobserved cells,
``v`` the heights about a reference: the observed cells' mean (``mean_kK``) or their
least-squares plane (``plane_kK``); ``k`` (1 / cells) is the screening of a Matern field's SPDE
(Lindgren et al. 2011: precision ``(k^2 - L)^2``), ``k = 0`` the thin plate (``mean_k0`` is the
thin plate, ``plane_k0`` the shipped model's base fill). Far from every observation a screened
fill returns to its reference within about ``1 / k`` cells instead of running a slope on. Solved
converged-ish (``biharmonic_fill``'s cascadic CG with many more steps), in float64.

Per map, three label-free judges pick a candidate: ``outer`` (the least error on the scan's
outermost 30 % of observed cells, hidden: ``selfcheck.outer_cells``), ``sector`` (the outer half
of the observed cells in every other 60 deg sector hidden: gaps that reach the map's edge) and
``variogram`` (the candidate's model variogram, nugget + scale fitted, closest to the observed
cells' empirical variogram in relative least squares). ``oracle`` is the per-map best against
the truth. RMSE (m) on unobserved cells.

usage: python tools/probes/far_field_fills.py [--size 16] octave3 octave5 "dem:mammoth 1 m, true" dem:finland dem:jacksboro
"""

import argparse
import math

import torch

from warp_terrain.evaluation.real import DEM_FAMILIES, dem_family_set, real_data_dir
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.selfcheck import outer_cells
from warp_terrain.models.biharmonic import biharmonic_fill
from warp_terrain.models.fill import mean_observed, observed_plane

KAPPAS = (0.0, 0.03, 0.06, 0.1)
STEPS = (200, 200, 200, 400, 800)
LAGS = torch.tensor([1, 2, 3, 4, 6, 8, 11, 16, 22, 32, 45, 64], dtype=torch.float64)


def screened_fill(height, mask, kappa: float, reference: str):
    """The candidate ``{reference}_k{kappa}`` (float64): ``biharmonic_fill(screening=kappa)`` of
    the heights about the reference, with the long step schedule."""
    height, mask = height.double(), mask.double()
    ref = observed_plane(height, mask) if reference == "plane" else mean_observed(height, mask).expand_as(height)
    return biharmonic_fill(height - ref, mask, steps=STEPS, screening=kappa) + ref


def candidates(scan, mask) -> dict:
    return {f"{ref}_k{k:g}": screened_fill(scan, mask, k, ref) for ref in ("mean", "plane") for k in KAPPAS}


def _binned(values, radius, edges):
    return torch.stack([(values * ((radius >= lo) & (radius < hi))).sum(dim=(-2, -1)) for lo, hi in zip(edges[:-1], edges[1:])], -1)


def _lag_grid(size: int):
    ax = torch.arange(size, dtype=torch.float64)
    ax = torch.where(ax < size // 2, ax, ax - size)
    return (ax[:, None] ** 2 + ax[None, :] ** 2).sqrt(), torch.cat([torch.tensor([0.5]), 0.5 * (LAGS[1:] + LAGS[:-1]), LAGS[-1:] * 1.25])


def empirical_variogram(z, m):
    """(B, L) isotropic semivariogram of the observed cells at ``LAGS`` and the pair counts."""
    size = 2 * z.shape[-1]
    z, m = z[:, 0].double() * m[:, 0], m[:, 0].double()

    def corr(a, b):
        return torch.fft.irfft2(torch.fft.rfft2(a, (size, size)) * torch.fft.rfft2(b, (size, size)).conj(), (size, size))

    pairs = corr(m, m)
    sums = corr(m * z * z, m) + corr(m, m * z * z) - 2 * corr(m * z, m * z)
    radius, edges = _lag_grid(size)
    count = _binned(pairs, radius, edges)
    return _binned(sums, radius, edges) / (2 * count.clamp_min(1)), count


def model_variogram(kappa: float, size: int = 256):
    """(L,) the variogram shape of the GMRF of precision ``(k^2 - L)^2`` on a periodic grid."""
    k = 2 * math.pi * torch.arange(size, dtype=torch.float64) / size
    lam = (2 - 2 * torch.cos(k))[:, None] + (2 - 2 * torch.cos(k))[None, :]
    spectrum = 1 / ((kappa**2 + lam) ** 2).clamp_min(1e-300)
    spectrum[0, 0] = 0.0
    cov = torch.fft.ifft2(spectrum).real
    radius, edges = _lag_grid(size)
    count = _binned(torch.ones_like(cov), radius, edges)
    return cov[0, 0] - _binned(cov, radius, edges) / count


def variogram_misfit(gamma, count, shape):
    """(B,) relative least-squares misfit of ``gamma ~ nugget + s shape`` (nugget >= 0)."""
    out = []
    for g, c in zip(gamma, count):
        w = (c > 20).double() / g.clamp_min(1e-12) ** 2
        a = torch.stack([torch.ones_like(shape), shape], 1)
        coef = torch.linalg.solve((a * w[:, None]).T @ a + 1e-12 * torch.eye(2, dtype=a.dtype), (a * w[:, None]).T @ g)
        if coef[0] < 0:
            coef = torch.stack([torch.zeros((), dtype=g.dtype), (shape * w * g).sum() / (shape * w * shape).sum()])
        out.append((w * (g - a @ coef) ** 2).sum() / w.gt(0).sum())
    return torch.stack(out)


def sector_cells(mask):
    size = mask.shape[-1]
    ax = torch.arange(size, dtype=torch.float32) - 0.5 * (size - 1)
    x, y = ax[:, None].expand(size, size), ax[None, :].expand(size, size)
    radius = (x**2 + y**2).sqrt()
    sector = torch.floor((torch.atan2(y, x) + math.pi) / (math.pi / 3)).long() % 2 == 0
    observed = mask[:, 0] > 0
    cut = torch.stack([torch.quantile(radius[o], 0.5) for o in observed])
    return (observed & sector & (radius > cut.view(-1, 1, 1)))[:, None]


def holdout_error(scan, mask, cells, names):
    kept = mask * (~cells).to(mask.dtype)
    fills = candidates(scan * kept, kept)
    return torch.stack([(((fills[k] - scan.double()) ** 2) * cells).sum(dim=(1, 2, 3)) for k in names])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("sets", nargs="+", help="a synthetic setting (clean scans), or dem:FAMILY (a prefix of a real-suite DEM family)")
    args = parser.parse_args()
    shapes = {k: model_variogram(k) for k in KAPPAS}
    for name in args.sets:
        if name.startswith("dem:"):
            family = next(f for f in DEM_FAMILIES if f.name.startswith(name[4:]))
            ts = dem_family_set(family, real_data_dir(), args.size, "cpu")
        else:
            ts = make_eval_set(name, 0.0, size=args.size, device="cpu")
        scan, mask, target = ts.scan, ts.mask, ts.target.double()
        fills = candidates(scan, mask)
        names = list(fills)
        unobserved = mask < 0.5
        errors = torch.stack([(((fills[k] - target) ** 2) * unobserved).sum(dim=(1, 2, 3)) for k in names])  # (K, B)
        n = unobserved.sum()
        print(f"{name} ({args.size} maps): " + "  ".join(f"{k} {float((e.sum() / n).sqrt()):.4f}" for k, e in zip(names, errors)))
        plane = observed_plane(scan.double(), mask.double())
        raw, residual = empirical_variogram(scan, mask), empirical_variogram(scan.double() - plane, mask)
        misfit = torch.stack([variogram_misfit(*(raw if k.startswith("mean") else residual), shapes[float(k.split("_k")[1])])
                              for k in names])
        scores = {"outer": holdout_error(scan, mask, outer_cells(mask), names), "sector": holdout_error(scan, mask, sector_cells(mask), names),
                  "variogram": misfit}
        picks = {judge: s.argmin(0) for judge, s in scores.items()}
        picks["oracle"] = errors.argmin(0)
        row = {judge: float((errors[p, torch.arange(p.numel())].sum() / n).sqrt()) for judge, p in picks.items()}
        print("  judged: " + "  ".join(f"{j} {v:.4f}" for j, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
