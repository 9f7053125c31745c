"""Where the checked sigma is too narrow and where too wide: the share of unobserved cells whose
error lies within the shipped model's 1 sigma, by distance to the nearest observed cell (cells),
from mean heights and from centred ones (``models.centring``). The check scales each map's sigma
on hidden observed cells, which lie on a ring with kept neighbours along it; an unobserved cell
one cell from the scan lies between rings. 32 maps per set (the sets of ``cell_centre.py``), no
orientation average.

usage: python tools/probes/sigma_by_distance.py
"""

import numpy as np
import torch
from cell_centre import sets
from common import load_checked
from scipy import ndimage

from warp_terrain.models.centring import centre_cells
from warp_terrain.sim.batch import generate_batch
from warp_terrain.sim.projection import cell_offsets

BINS = ((1, 1), (2, 2), (3, 4), (5, 8), (9, 16), (17, None))


def main():
    rec = load_checked("shipped", tta=False)
    heads = [f"{a} cells" if a == b else f"{a}-{b}" if b else f"{a}+" for a, b in BINS]
    print("| set | cell height | " + " | ".join(f"{h}: share, within 1 sigma" for h in heads) + " |")
    print("|---|---|" + "---:|" * len(BINS))
    for name, sim, seeds in sets(32, False):
        chunk = 32 // len(seeds)
        parts = [generate_batch(chunk, sim, seed=s, device="cpu") for s in seeds]
        scan, mask, target = (torch.cat([getattr(b, k) for b in parts]) for k in ("scan", "mask", "target"))
        cell, size = sim.data.map_cell, sim.data.map_size
        offset = torch.cat([cell_offsets(b.points, size, cell, device="cpu") for b in parts])
        distance = torch.from_numpy(np.stack([ndimage.distance_transform_edt(m[0].numpy() == 0) for m in mask]))[:, None]
        unobserved = mask == 0
        for label, h in (("mean", scan * mask), ("centred", centre_cells(scan, mask, offset, cell))):
            outs = [rec.predict_maps_with_uncertainty(h[i:i + 16], mask[i:i + 16]) for i in range(0, h.shape[0], 16)]
            pred, sigma = torch.cat([o[0] for o in outs]), torch.cat([o[1] for o in outs])
            within = (pred - target).abs() <= sigma
            cells = []
            for a, b in BINS:
                chosen = unobserved & (distance >= a - 0.5) & (distance < (b if b else 1e9) + 0.5)
                share = float(chosen.sum() / unobserved.sum())
                cells.append(f"{share:.0%}, {float(within[chosen].float().mean()):.0%}" if bool(chosen.any()) else f"{share:.0%}, -")
            print(f"| {name} | {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
