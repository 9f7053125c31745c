"""Probe (docs/transfer.md): what the shipped check decides per map of a synthetic
setting, beside what each candidate scores there. Per map: the smooth fill it picks (0 the base
fill, 1 the thin plate), the membrane's share near / far, the net's near weight, and the RMSE on
unobserved cells of the net alone, the checked map, the base fill and the membrane; then both
maps' RMSE within 8 cells of the scan and beyond. No orientation average.

    python tools/probes/check_per_map.py SETTING NOISE [SIZE]     e.g. flat_cylinders 0 16
"""

import sys

import torch
from common import load_checked

from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.selfcheck import Regimes, best_fill, check_cells, far_share, pick


def main(setting: str, noise: str, size: str = "16") -> None:
    torch.set_num_threads(2)
    ts = make_eval_set(setting, float(noise), size=int(size), device="cpu")
    rec = load_checked("shipped", tta=False)
    scan, mask, n = ts.scan, ts.mask, ts.scan.shape[0]
    hidden, outer, thinned = check_cells(mask)
    with torch.inference_mode():
        heights, _, fills = rec._predict(torch.cat([scan, scan * thinned]), torch.cat([mask, thinned]), rec.check_tensions)
        checked, _ = rec._predict_checked(scan, mask)
    regimes = Regimes(hidden, outer)
    choice = best_fill(fills[:-1, n:], scan, hidden)
    smooth_thinned = pick(fills[:-1, n:], choice)
    beta = regimes.weight(fills[-1, n:], smooth_thinned, scan)
    fill_thinned = regimes.apply(beta, smooth_thinned, fills[-1, n:], thinned)
    w = regimes.weight(heights[n:], fill_thinned, scan)
    unobserved = mask < 0.5
    for i in range(n):
        def rmse(p, i=i):
            return float((p[i] - ts.target[i])[unobserved[i]].square().mean().sqrt())
        print(f"map {i:2d} choice {int(choice[i])} membrane {float(beta[0][i]):.2f} / {float(beta[1][i]):.2f} net weight {float(w[0][i]):.2f} | "
              f"RMSE net {rmse(heights[:n]):.4f} checked {rmse(checked):.4f} base fill {rmse(fills[0, :n]):.4f} membrane {rmse(fills[-1, :n]):.4f}")
    far = far_share(mask) >= 1
    for name, p in (("net", heights[:n]), ("checked", checked)):
        d = p - ts.target
        print(f"{name:8s} RMSE within 8 cells of the scan {float(d[unobserved & ~far].square().mean().sqrt()):.4f}, "
              f"beyond {float(d[unobserved & far].square().mean().sqrt()):.4f} ({float((unobserved & far).sum() / unobserved.sum()):.1%} of the unobserved cells)")


if __name__ == "__main__":
    main(*sys.argv[1:])
