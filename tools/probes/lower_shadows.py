"""The self-check's shadow test run on the lower of the fill and the net's own map (stop 47).

usage: python tools/probes/lower_shadows.py tools/real_ablation.py --fills-cache FILE NAME_check=MODEL ...

The check keeps the net's correction whole in the scan's shadows, the unobserved cells whose
*fill* lies below the horizon (``inference/shadows.shadow_cells``). Across a pit the fill
bridges rim to far wall above the line of sight, so a pit's interior is no shadow to the check
(``tools/probes/pit_shadows.py``). This probe runs any tool (its first argument, with the
rest as that tool's arguments) with the shadow test given ``min(fill, net's map)`` instead, by
wrapping ``checked_maps`` and ``shadow_cells`` for the run: a measurement of the idea before it
becomes a flag of the file. Not part of the package or the suite.
"""

import runpy
import sys

import torch

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as selfcheck

_net = {}
_checked_maps, _shadow_cells = reconstructor.checked_maps, selfcheck.shadow_cells


def checked_maps(fills, model, *args, **kwargs):
    _net["maps"] = model  # (2N, 1, S, S): the full scans' maps, then the thinned scans', as the fills
    return _checked_maps(fills, model, *args, **kwargs)


def shadow_cells(scan, mask, fill, margin=0.0):
    return _shadow_cells(scan, mask, torch.minimum(fill, _net["maps"].to(fill.dtype)), margin)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__.splitlines()[2])
    reconstructor.checked_maps, selfcheck.shadow_cells = checked_maps, shadow_cells
    sys.argv = sys.argv[1:]
    runpy.run_path(sys.argv[0], run_name="__main__")
