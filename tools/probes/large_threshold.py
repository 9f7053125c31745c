"""Probe (docs/transfer.md, stop 42): the large-correction threshold of the check
(``selfcheck.LARGE_CORRECTION``, 0.3 m) swept on the synthetic suite's sets.

The shipped file's check (shadows on, the random hidden cells refuting) with each threshold, or
none, over the same net and fills: RMSE on unobserved cells, and the obstacle IoU (cylinders) or
pit recall (pits), 64 maps per set, as ``warp-terrain evaluate`` scores them; the last column
is the net's own map, unchecked. One pass of the
model per set; the thresholds are applied to its maps.

usage: python tools/probes/large_threshold.py
"""

import torch
from common import load_checked

from warp_terrain.evaluation.metrics import masked_rmse, obstacle_iou, pit_recall
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.selfcheck import SHADOW_MARGIN, Regimes, check_cells, checked_maps, scan_noise

THRESHOLDS = (None, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, "net")  # "net": the net's own map, unchecked
SETS = (("flat_cylinders", 0.0), ("negative_obstacles", 0.0), ("flat_cylinders", 0.05), ("negative_obstacles", 0.05),
        ("octave5", 0.0), ("octave3", 0.0))


def main() -> None:
    torch.set_num_threads(2)
    rec = load_checked("shipped")
    print("| set | " + " | ".join("off" if t is None else "net alone" if t == "net" else f"{t} m" for t in THRESHOLDS) + " |")
    print("|---|" + "---:|" * len(THRESHOLDS))
    for setting, noise in SETS:
        ts = make_eval_set(setting, noise, size=64, device="cpu")
        maps = {t: [] for t in THRESHOLDS}
        with torch.inference_mode():
            for i in range(0, ts.scan.shape[0], 16):
                scan, mask = ts.scan[i:i + 16], ts.mask[i:i + 16]
                hidden, outer, thinned = check_cells(mask, True)
                both_scans, both_masks = torch.cat([scan, scan * thinned]), torch.cat([mask, thinned])
                margin = SHADOW_MARGIN * scan_noise(both_scans, both_masks)
                heights, _, fills = rec._predict(both_scans, both_masks, rec.check_tensions, noise=margin / SHADOW_MARGIN)
                regimes = Regimes(hidden, outer, masks=(mask, thinned))
                maps["net"].append(heights[: scan.shape[0]])
                for t in THRESHOLDS[:-1]:
                    maps[t].append(checked_maps(fills, heights, scan, mask, thinned, regimes, True, True, margin, t)[0])
        cells = []
        for t in THRESHOLDS:
            pred = torch.cat(maps[t])
            rmse = masked_rmse(pred.float(), ts.target, ts.mask < 0.5)
            if setting == "flat_cylinders":
                cells.append(f"{rmse:.4f}, IoU {obstacle_iou(pred, ts.target, ts.ground):.3f}")
            elif setting == "negative_obstacles":
                cells.append(f"{rmse:.4f}, recall {pit_recall(pred, ts.target, ts.ground):.3f}")
            else:
                cells.append(f"{rmse:.4f}")
        print(f"| {setting}/{noise} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
