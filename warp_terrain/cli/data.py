"""``warp-terrain generate`` (a seeded dataset on disk) and ``warp-terrain preview`` (a PNG of samples)."""

from __future__ import annotations

import json
import sys

from .args import _add_device
from .progress import _add_quiet, reporters


# ------------------------------------------------------------------------------ generate
def add_generate(sub) -> None:
    p = sub.add_parser("generate", help="write a fixed, seeded dataset to disk (sharded .npz + manifest.json)",
                       description="Generate N training pairs into DIR as shard-NNNNN.npz files (scan, mask, target: float32 "
                                   "(n, 1, S, S)) and manifest.json (config, seeds, package version, shapes, sha256 per "
                                   "shard). Shard k = generate_batch(n_k, cfg, seed=batch_seed(SEED, 0, k)), i.e. batch k "
                                   "of the training stream with train.seed=SEED and train.batch_size=K. Train on it with "
                                   "train.dataset=DIR.")
    p.add_argument("count", type=int, metavar="N", help="number of pairs")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write (created if missing; must be empty unless --overwrite)")
    p.add_argument("--config", default=None, metavar="run_config.yaml",
                   help="a run config (e.g. a run folder's run_config.yaml): its terrain, lidar and data sections")
    p.add_argument("--terrain", default=None, metavar="NAME", help="terrain setting or terrain .yaml (default: octave5, or the config's)")
    p.add_argument("--lidar", default=None, metavar="NAME", help="LIDAR preset (default: hdl32e, or the config's)")
    p.add_argument("--noise", type=float, default=None, metavar="X", help="image noise as a fraction of the height range (e.g. 0.05)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (default: 0)")
    p.add_argument("--shard-size", type=int, default=64, metavar="K", help="pairs per shard (default: 64)")
    p.add_argument("--with-points", action="store_true", help="also store the LIDAR points (large)")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="make shards in N processes on a CPU (a Warp CPU launch uses one core); same files (default: 0, in-process)")
    p.add_argument("--overwrite", action="store_true", help="replace the dataset in a non-empty folder")
    p.add_argument("--json", action="store_true", help="print the manifest as JSON on stdout")
    _add_quiet(p)
    _add_device(p)
    p.set_defaults(func=cmd_generate)


def _generate_config(args):
    from ..compose import load_terrain_setting
    from ..sim import as_sim_config, lidar_preset

    if args.config is not None:
        from omegaconf import OmegaConf

        try:
            loaded = OmegaConf.load(args.config)
        except FileNotFoundError:
            raise ValueError(f"config={args.config!r}: no such file") from None
        except Exception as err:
            raise ValueError(f"config={args.config!r}: cannot read it ({type(err).__name__})") from None
        try:
            sim = as_sim_config(loaded)
        except ValueError:
            raise
        except Exception as err:
            first = (str(err).strip().splitlines() or [type(err).__name__])[0]
            raise ValueError(f"config={args.config!r}: not a run config ({first})") from None
        if args.terrain is not None:
            sim.terrain = load_terrain_setting(args.terrain).terrain
    else:
        sim = load_terrain_setting(args.terrain or "octave5", augment=True)  # the training default's data settings
    if args.lidar is not None:
        sim.lidar = lidar_preset(args.lidar)
    if args.noise is not None:
        sim.data.noise = args.noise
    try:
        sim.validate()
    except ValueError as err:
        raise ValueError(f"data.{err}" if str(err).startswith("noise") else str(err)) from None
    return sim


def cmd_generate(args) -> int:
    from ..data.disk import write_dataset

    sim = _generate_config(args)

    progress, track = reporters(args.quiet, "shard")
    manifest = write_dataset(args.out, args.count, sim, seed=args.seed, shard_size=args.shard_size, overwrite=args.overwrite,
                             with_points=args.with_points, device=args.device, progress=progress, workers=args.workers, track=track)
    if args.json:
        json.dump(manifest, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(f"wrote {manifest['count']} pairs in {len(manifest['shards'])} shards to {args.out}", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ preview
def add_preview(sub) -> None:
    p = sub.add_parser("preview", help="write a PNG figure of generated samples",
                       description="Render terrain, LIDAR returns, scan image, mask and ground truth of one sample "
                                   "per terrain setting (conf/terrain/*.yaml) into a PNG.")
    p.add_argument("--out", required=True, metavar="PATH.png", help="PNG file to write (its folder must exist)")
    p.add_argument("--terrain", default="octave5", metavar="NAME",
                   help="terrain setting (octave3, octave5, flat_cylinders, negative_obstacles), a comma-separated "
                        "list, 'all' (one row each) or a path to a terrain .yaml (default: octave5)")
    p.add_argument("--seed", type=int, default=0, help="sample seed (default: 0)")
    p.add_argument("--dpi", type=int, default=80, help="resolution of the PNG (default: 80)")
    _add_device(p)
    p.set_defaults(func=cmd_preview)


def cmd_preview(args) -> int:
    from ..plots.preview import write_preview

    out = write_preview(args.out, terrain=args.terrain, seed=args.seed, device=args.device, dpi=args.dpi)
    print(f"wrote {out}", file=sys.stderr)
    return 0
