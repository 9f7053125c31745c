"""Probe (docs/transfer.md): can a judge learned on the training world pick a
map's far field? Per map of the shipped recipe's own world (validation seeds, never trained on)
and of the suites' sets: the least-squares share ``lam`` of ``Y - X`` (``far_field_judge.py``:
``X`` the shipped map, ``Y`` its far field from the picked smooth fill) against the truth on
unobserved cells, clamped to [0, 1], beside label-free statistics of the scan. Prints each
statistic's rank correlation with ``lam`` per set, then fits a logistic judge on the training
world's maps (statistics standardised on them) and scores it on every set: RMSE of ``X``, of
``Y``, of the judged blend ``X + p (Y - X)`` and of the per-map oracle. No orientation average.

    python tools/probes/far_field_features.py [--fit-size 256] [--size 32]
"""

import argparse
import math

import torch
import transplant
from common import load_checked
from far_field_judge import plane_statistics, predict, sets, sse

from warp_terrain.compose import compose_run
from warp_terrain.data.seeds import validation_seed
from warp_terrain.inference import reconstructor
from warp_terrain.inference import selfcheck as check
from warp_terrain.models.fill import observed_plane
from warp_terrain.sim import as_sim_config
from warp_terrain.sim.batch import generate_batch

FEATURES = ("tilt", "plane_r2", "vario_mean", "vario_plane", "outer_pref", "xy_spread", "observed", "noise_rel")


def variogram_ratio(resid, obs, short=2, long=8):
    """(B,) log of the mean squared increment at ``long`` cells over that at ``short``, rows and columns."""
    out = []
    for lag in (short, long):
        num = resid.new_zeros(resid.shape[0])
        den = resid.new_zeros(resid.shape[0])
        for dim in (2, 3):
            n = resid.shape[dim] - lag
            a, b = resid.narrow(dim, 0, n), resid.narrow(dim, lag, n)
            both = (obs.narrow(dim, 0, n) & obs.narrow(dim, lag, n)).to(resid.dtype)
            num += (((a - b) ** 2) * both).sum(dim=(1, 2, 3))
            den += both.sum(dim=(1, 2, 3))
        out.append(num / den.clamp_min(1))
    return torch.log(out[1].clamp_min(1e-12) / out[0].clamp_min(1e-12))


def features_and_labels(rec, scan, mask, target, cell):
    """(features (B, F), lam (B,), D (B,), sse of X, differ (B,) bool, unobserved cells): the blend
    ``X + p (Y - X)`` errs ``ex + D (p^2 - 2 p lam)`` on a map's unobserved cells."""
    x, y = predict(rec, scan, mask, "X"), predict(rec, scan, mask, "Y")
    unobs = (mask == 0).to(x.dtype)
    d = (y - x) * unobs
    D = (d * d).sum(dim=(1, 2, 3))
    lam = (d * (target - x)).sum(dim=(1, 2, 3)) / D.clamp_min(1e-12)  # unclamped: the blend's error is ex + D (p^2 - 2 p lam)
    obs = mask > 0
    tilt, r2 = plane_statistics(scan, mask, cell)
    plane = observed_plane(scan, mask)
    count = obs.sum(dim=(1, 2, 3)).clamp_min(1)
    mean = (scan * obs).sum(dim=(1, 2, 3)) / count
    std = ((((scan - mean.view(-1, 1, 1, 1)) ** 2) * obs).sum(dim=(1, 2, 3)) / count).sqrt().clamp_min(1e-6)
    outer = check.outer_cells(mask)
    ox, oy = sse(x, scan, outer), sse(y, scan, outer)
    far = check.far_share(mask) >= 1
    spread = ((d**2) * far).sum(dim=(1, 2, 3)).div(far.sum(dim=(1, 2, 3)).clamp_min(1)).sqrt() / std
    noise = check.scan_noise(scan, mask).flatten() / std
    feats = torch.stack(
        [
            torch.tensor(tilt),
            torch.tensor(r2),
            variogram_ratio(scan - mean.view(-1, 1, 1, 1), obs),
            variogram_ratio(scan - plane, obs),
            (ox - oy) / (ox + oy).clamp_min(1e-12),
            spread,
            obs.float().mean(dim=(1, 2, 3)),
            noise,
        ],
        dim=1,
    ).float()
    return feats, lam, D, sse(x, target, unobs), d.abs().sum(dim=(1, 2, 3)) > 1e-6, unobs.sum()


def spearman(a, b):
    ra, rb = a.argsort().argsort().float(), b.argsort().argsort().float()
    ra, rb = ra - ra.mean(), rb - rb.mean()
    return float((ra * rb).sum() / (ra.norm() * rb.norm()).clamp_min(1e-12))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fit-size", type=int, default=256)
    parser.add_argument("--size", type=int, default=32)
    args = parser.parse_args()
    torch.set_num_threads(2)
    reconstructor.checked_maps = transplant.checked_maps
    rec = load_checked("shipped", tta=False)
    sim = as_sim_config(compose_run(["experiment=pretrained_cycle1"]))
    rows = []
    for i in range(args.fit_size // 16):
        b = generate_batch(16, sim, seed=validation_seed(300 + i), device="cpu")
        rows.append(features_and_labels(rec, b.scan * b.mask, b.mask, b.target, sim.data.map_cell))
    fit = [torch.cat([r[k] for r in rows]) for k in range(5)]
    data = {"training world (fit)": (fit, float(sum(r[5] for r in rows)))}
    for name, ts in sets(args.size):
        out = features_and_labels(rec, ts.scan, ts.mask, ts.target, ts.sim.data.map_cell)
        data[name] = (list(out[:5]), float(out[5]))
    print("| set | maps that differ | median lam | " + " | ".join(FEATURES) + " |")
    print("|---|---:|---:|" + "---:|" * len(FEATURES))
    for name, ((f, lam, _, _, differ), _) in data.items():
        lam = lam.clamp(0, 1)
        cors = [f"{spearman(f[differ, j], lam[differ]):+.2f}" for j in range(len(FEATURES))]
        print(f"| {name} | {int(differ.sum())} | {float(lam[differ].median()):.2f} | " + " | ".join(cors) + " |", flush=True)
    # a logistic judge fitted on the training world: p = sigmoid(w . standardised features + b), loss
    # the far field's squared error itself (the blend X + p (Y - X) is linear in p per map)
    f, lam, D, ex, differ = fit
    mu, sd = f.mean(0), f.std(0).clamp_min(1e-6)
    w = torch.zeros(f.shape[1], requires_grad=True)
    b0 = torch.zeros(1, requires_grad=True)
    opt = torch.optim.LBFGS([w, b0], max_iter=200)
    z = (f - mu) / sd
    scale = D.sum().clamp_min(1e-12)

    def closure():  # the training world's far-field squared error itself, summed over its maps
        opt.zero_grad()
        p = torch.sigmoid(z @ w + b0)
        loss = (D * (p**2 - 2 * p * lam)).sum() / scale + 1e-3 * (w**2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    print("judge weights (standardised):", ", ".join(f"{k} {float(v):+.2f}" for k, v in zip(FEATURES, w.detach())), f"bias {float(b0):+.2f}")
    print("| set | X | Y | judged | oracle |")
    print("|---|---:|---:|---:|---:|")
    for name, ((f, lam, D, ex, _), cells) in data.items():
        p = torch.sigmoid(((f - mu) / sd) @ w.detach() + b0.detach())
        ey, ej, eo = (ex + D * (q**2 - 2 * q * lam) for q in (torch.ones_like(p), p, lam.clamp(0, 1)))
        print(f"| {name} | {math.sqrt(ex.sum() / cells):.4f} | {math.sqrt(ey.sum() / cells):.4f} | "
              f"{math.sqrt(ej.sum() / cells):.4f} | {math.sqrt(eo.sum() / cells):.4f} |", flush=True)


if __name__ == "__main__":
    main()
