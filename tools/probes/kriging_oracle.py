"""Probe (README, "How far the synthetic targets can go"): the best *linear* fill of a synthetic
setting, for scale. Ordinary kriging with the setting's own covariance, known exactly (an
oracle no real scan offers): the covariance is the periodogram of large fields of the same fBm
(``fractal_heightfield``, 8 x 4 fields of 1024^2 map cells, averaged 2x2 from the terrain's
0.125 m to the map's 0.25 m; a periodogram's covariance is positive definite, unlike a sampled
variogram), the observation error is the scan's own on its observed cells. Kriging is the
posterior mean of a Gaussian field: no linear method can beat it on average, and a model that
stays near the thin plate on clean fBm leaves the gap between the two. Also prints, per distance
to the nearest observed cell, where the thin plate's squared error lies.

usage: python tools/probes/kriging_oracle.py [--size 16] octave5/0 octave3/0 octave5/0.1 ...
(each map is one dense solve of ~4,000 observed cells: about 9 s per map on this CPU)
"""

import argparse
import time

import numpy as np
import torch
import torch.nn.functional as F
from scipy import linalg

import warp_terrain as wt
from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.inference.selfcheck import far_share

FIELD = 1024  # map cells per side of the fields the periodogram is taken of


def covariance(terrain, size: int) -> np.ndarray:
    """``C[di + size - 1, dj + size - 1]``: the covariance (m^2) of map heights ``(di, dj)`` cells apart."""
    power = np.zeros((FIELD, FIELD))
    count = 0
    for seed in range(8):
        h = wt.fractal_heightfield(4, 2 * FIELD, cell=terrain.cell, octaves=terrain.octaves, persistence=terrain.persistence,
                                   lacunarity=terrain.lacunarity, feature_size=terrain.feature_size, amplitude=terrain.amplitude,
                                   seed=500 + seed, device="cpu")
        for z in F.avg_pool2d(h[:, None].double(), 2)[:, 0].numpy():
            power += np.abs(np.fft.fft2(z - z.mean())) ** 2
            count += 1
    cov = np.real(np.fft.ifft2(power)) / (FIELD * FIELD * count)
    lags = np.arange(-(size - 1), size) % FIELD
    return cov[np.ix_(lags, lags)]


def krige(scan: np.ndarray, observed: np.ndarray, cov: np.ndarray, nugget: float) -> np.ndarray:
    """Ordinary kriging (unknown constant mean) of the unobserved cells of one map."""
    size = scan.shape[0]
    c = size - 1
    ii, jj = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    pi, pj, z = ii[observed], jj[observed], scan[observed]
    qi, qj = ii[~observed], jj[~observed]
    n = z.size
    system = np.ones((n + 1, n + 1))
    system[:n, :n] = cov[pi[:, None] - pi[None, :] + c, pj[:, None] - pj[None, :] + c] + nugget * np.eye(n)
    system[n, n] = 0.0
    rhs = np.ones((n + 1, qi.size))
    rhs[:n] = cov[pi[:, None] - qi[None, :] + c, pj[:, None] - qj[None, :] + c]
    weights = linalg.lu_solve(linalg.lu_factor(system), rhs)
    out = scan.copy()
    out[~observed] = weights[:n].T @ z
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=16, help="maps per setting (the first of its test set)")
    parser.add_argument("settings", nargs="+", help="SETTING/NOISE, e.g. octave5/0")
    args = parser.parse_args()
    model = Reconstructor.load(device="cpu")
    for spec in args.settings:
        setting, noise = spec.split("/")
        ts = make_eval_set(setting, float(noise), size=args.size, device="cpu")
        t0 = time.perf_counter()
        cov = covariance(ts.sim.terrain, ts.sim.data.map_size)
        nugget = float((((ts.scan - ts.target) * ts.mask) ** 2).sum() / ts.mask.sum())
        kriged = torch.stack([torch.from_numpy(krige(s[0].double().numpy(), m[0].numpy() > 0, cov, nugget)).float()[None]
                              for s, m in zip(ts.scan, ts.mask)])
        unobserved = ts.mask < 0.5
        preds = {"kriging (oracle)": kriged, "model (shipped)": model.predict_maps(ts.scan, ts.mask)}
        preds.update({name: BASELINES[name](ts.scan, ts.mask) for name in ("biharmonic", "harmonic")})
        rmse = {k: float(((p - ts.target)[unobserved] ** 2).mean().sqrt()) for k, p in preds.items()}
        best = min(rmse["biharmonic"], rmse["harmonic"])
        print(f"{spec}: {args.size} maps, {time.perf_counter() - t0:.0f} s; RMSE on unobserved cells (m) and / best classical fill")
        for name, value in rmse.items():
            print(f"  {name:18s} {value:.4f}  {value / best:.2f}")
        # far_share(near=8, far=9) is 1 exactly on cells 9 or more cells from every observed cell
        far = (far_share(ts.mask, near=8, far=9) > 0.5) & unobserved
        thin = (preds["biharmonic"] - ts.target) ** 2
        print(f"  cells >= 9 cells from the scan: {float(far.sum() / unobserved.sum()):.1%} of the unobserved, "
              f"{float(thin[far].sum() / thin[unobserved].sum()):.0%} of the thin plate's squared error; RMSE there: "
              + ", ".join(f"{k} {float(((p - ts.target)[far] ** 2).mean().sqrt()):.3f}" for k, p in preds.items()), flush=True)


if __name__ == "__main__":
    main()
