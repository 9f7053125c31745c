"""``warp-terrain figures`` (the paper's figure kinds as PNGs) and ``warp-terrain export-usd``
(one sample, and a model's reconstruction of it, as a USD stage)."""

from __future__ import annotations

import sys

from .args import _add_device


# ------------------------------------------------------------------------------ figures
def add_figures(sub) -> None:
    p = sub.add_parser("figures", help="write the paper's figure kinds as PNGs",
                       description="Write the paper's figure kinds into a folder: Fig. 1 (heightmaps for several octave "
                                   "counts) and Fig. 3 (scan image with and without noise) from the simulator; with "
                                   "--checkpoint also Fig. 5 (original vs reconstructed 3-D terrain), Fig. 6 (input | "
                                   "prediction | ground truth) and Figs. 7, 8 (obstacle and negative-obstacle predictions).")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the PNGs (created if missing)")
    p.add_argument("--checkpoint", default=None, metavar="PATH", help="a training checkpoint (checkpoints/latest.pt or best.pt) for Figs. 5-8")
    p.add_argument("--seed", type=int, default=0, help="sample seed (default: 0)")
    p.add_argument("--dpi", type=int, default=80, help="resolution of the PNGs (default: 80)")
    _add_device(p)
    p.set_defaults(func=cmd_figures)


def cmd_figures(args) -> int:
    from ..plots.paper import write_figures

    written = write_figures(args.out, checkpoint=args.checkpoint, seed=args.seed, device=args.device, dpi=args.dpi)
    for path in written.values():
        print(path)
    if args.checkpoint is None:
        print("Figs. 5-8 need a model: pass --checkpoint PATH", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ export-usd
def add_export_usd(sub) -> None:
    p = sub.add_parser("export-usd", help="generate a sample and export it as a USD stage",
                       description="Generate one sample of a terrain setting and write its terrain mesh (and optionally "
                                   "its LIDAR points and a model's reconstruction with its error map) to a .usda or .usdc stage.")
    p.add_argument("out", metavar="OUT.usda|OUT.usdc", help="the stage to write (its folder must exist)")
    p.add_argument("--terrain", default=None, metavar="NAME",
                   help="terrain setting (octave3, octave5, flat_cylinders, negative_obstacles) or a terrain .yaml "
                        "(default: octave5, or the checkpoint's terrain)")
    p.add_argument("--seed", type=int, default=0, help="sample seed (default: 0)")
    p.add_argument("--with-points", action="store_true", help="add the LIDAR returns as UsdGeom.Points")
    p.add_argument("--checkpoint", default=None, metavar="PATH",
                   help="a training checkpoint: add its reconstruction and the error map (the sample uses the checkpoint's lidar and maps)")
    p.add_argument("--png", default=None, metavar="PATH.png", help="also draw the written stage into this PNG (matplotlib 3-D)")
    _add_device(p)
    p.set_defaults(func=cmd_export_usd)


def cmd_export_usd(args) -> int:
    import copy

    from ..compose import load_terrain_setting
    from ..export.scene import export_sample
    from ..export.usd import check_usd_path
    from ..inference.predictor import load_predictor
    from ..plots.common import check_png_path
    from ..plots.usd import write_usd_figure
    from ..sim import resolve_device

    out = check_usd_path(args.out)  # fail before any work
    if args.png is not None:
        check_png_path(args.png)
    device = resolve_device(args.device)
    predictor = None
    if args.checkpoint is not None:
        predictor = load_predictor(None if args.checkpoint == "pretrained" else args.checkpoint, device, tta=False)
        sim = copy.deepcopy(predictor.sim or load_terrain_setting("octave5"))
        if args.terrain is not None:
            sim.terrain = load_terrain_setting(args.terrain).terrain
    else:
        sim = load_terrain_setting(args.terrain or "octave5")
    out = export_sample(out, sim, args.seed, predictor=predictor, with_points=args.with_points, device=device)
    print(out)
    if args.png is not None:
        print(write_usd_figure(out, args.png))
    return 0
