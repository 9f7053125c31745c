"""Probe (docs/transfer.md): which far field a map wants, and what the scan says.

``transplant.py`` found the families split by the far field (8+ cells from the scan): the
shipped map there is the net's (``X``: its base fill, the thin plate about the observed cells'
plane, plus its correction), while the smooth fill the check picks plus the same correction
(``Y``) returns towards the observed mean where that fill is the plain thin plate (its solve
starts from the mean and has not settled in the corners). Per map this prints both maps' RMSE
on unobserved cells, the per-map oracle (each map the better of the two, by the truth: what a
perfect judge would buy) and label-free statistics of the scan beside the truth's verdict: the
observed cells' plane (its tilt, the share of their variance it explains) and the check's outer
cells (which of the two errs less there). No orientation average.

    python tools/probes/far_field_judge.py [--size 16] [--only octave3 ...] [--model CHECKPOINT]
"""

import argparse
import math

import torch
import transplant
from common import load_checked

from warp_terrain.evaluation.real import DEM_FAMILIES, dem_family_set, real_data_dir
from warp_terrain.evaluation.robustness import synthetic_edge_sets
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference import reconstructor
from warp_terrain.inference import selfcheck as check
from warp_terrain.models.fill import observed_plane


def sets(size, only=None):
    """``(name, set)`` of the clean fBm settings, the DEM families without obstacles and the
    synthetic edge sets; with ``only`` just the sets of those names (the others are not built)."""
    wanted = lambda name: not only or name in only  # noqa: E731
    for setting in ("octave3", "octave5"):
        if wanted(setting):
            yield setting, make_eval_set(setting, 0.0, size=size, device="cpu")
    folder = real_data_dir()
    for family in DEM_FAMILIES:
        if not family.obstacles and wanted(family.name):
            yield family.name, dem_family_set(family, folder, size, "cpu")
    if not only or set(only) - {"octave3", "octave5"} - {f.name for f in DEM_FAMILIES}:
        for ts in synthetic_edge_sets(size, "cpu"):
            if wanted(ts.terrain):
                yield ts.terrain, ts


def plane_statistics(scan, mask, cell):
    """(tilt in degrees, share of the observed heights' variance the plane explains), per map."""
    plane = observed_plane(scan, mask)
    obs = mask > 0
    tilts, r2 = [], []
    for b in range(scan.shape[0]):
        z, p = scan[b][obs[b]], plane[b][obs[b]]
        total = float(((z - z.mean()) ** 2).mean())
        r2.append(1.0 - float(((z - p) ** 2).mean()) / max(total, 1e-12))
        gy, gx = torch.gradient(plane[b, 0], spacing=cell)
        tilts.append(math.degrees(math.atan(float(torch.sqrt(gx.mean() ** 2 + gy.mean() ** 2)))))
    return tilts, r2


def sse(pred, truth, cells):
    """(B,) squared error of each map over ``cells``."""
    return (((pred - truth) ** 2) * cells.to(pred.dtype)).sum(dim=(1, 2, 3))


def predict(rec, scan, mask, kind):
    transplant.PROBE.clear()
    transplant.PROBE["split"] = ("A", kind)
    return torch.cat([rec.predict_maps(scan[i : i + 16], mask[i : i + 16]) for i in range(0, scan.shape[0], 16)])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--only", nargs="*", help="the sets to run, by name (default: all)")
    parser.add_argument("--model", default="shipped", help="a Reconstructor file or checkpoint, checked as the shipped file is")
    args = parser.parse_args()
    torch.set_num_threads(2)
    reconstructor.checked_maps = transplant.checked_maps
    rec = load_checked(args.model, tta=False)
    print("| set | X | Y | oracle | maps Y better | tilt: Y / X maps | plane R2: Y / X maps | outer cells agree |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, ts in sets(args.size, args.only):
        scan, mask, target = ts.scan, ts.mask, ts.target
        x, y = predict(rec, scan, mask, "X"), predict(rec, scan, mask, "Y")
        unobs = (mask == 0).float()
        ex, ey, cells = sse(x, target, unobs), sse(y, target, unobs), unobs.sum()
        better = ey < ex
        outer = check.outer_cells(mask)
        ox, oy = sse(x, scan, outer), sse(y, scan, outer)
        differ = (ex - ey).abs() > 1e-9
        agree = ((oy < ox) == better)[differ].float().mean() if differ.any() else torch.tensor(float("nan"))
        tilt, r2 = plane_statistics(scan, mask, ts.sim.data.map_cell)
        tilt, r2 = torch.tensor(tilt), torch.tensor(r2)
        pick = lambda v, m: f"{float(v[m].median()):.2f}" if m.any() else "-"  # noqa: E731
        print(f"| {name} | {math.sqrt(ex.sum() / cells):.4f} | {math.sqrt(ey.sum() / cells):.4f} | "
              f"{math.sqrt(torch.minimum(ex, ey).sum() / cells):.4f} | {int(better.sum())} / {int(differ.sum())} | "
              f"{pick(tilt, better & differ)} / {pick(tilt, ~better & differ)} | {pick(r2, better & differ)} / {pick(r2, ~better & differ)} | "
              f"{float(agree):.0%} |", flush=True)


if __name__ == "__main__":
    main()
