"""The ``warp-terrain`` command line: one sub-command per everyday task.

Each sub-command is a ``cmd_<name>(args) -> int`` function registered in :func:`build_parser`
by an ``add_<name>(subparsers)`` function; to add one, write both and list the adder in
``SUBCOMMANDS``. Sub-commands only parse and call the library. Exit codes: 0 on success, 2 for
bad arguments (argparse's usage error, or ``error: <message>`` for a ``ValueError`` raised by
the library while checking them).
"""

from __future__ import annotations

import argparse
import json
import sys

from ..core.version import __version__
from ..core.atomic import atomic_open

EXIT_USAGE = 2

BENCH_NAMES = ("noise", "rays", "stream", "loader", "train", "infer")


# ------------------------------------------------------------------------------ argument types
def _device(value: str) -> str:
    if value == "cpu" or value == "cuda" or (value.startswith("cuda:") and value[5:].isdigit()):
        return value
    raise argparse.ArgumentTypeError(f"invalid device {value!r}: expected cpu, cuda or cuda:N")


def _only(value: str) -> list[str]:
    names = [s.strip() for s in value.split(",") if s.strip()]
    unknown = [n for n in names if n not in BENCH_NAMES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown benchmark {', '.join(unknown) or value!r}: choose from {','.join(BENCH_NAMES)}")
    return names


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", type=_device, default=None, metavar="{cpu,cuda}",
                   help="where the kernels run (default: CUDA if available, else CPU)")


# ------------------------------------------------------------------------------ bench
def add_bench(sub) -> None:
    p = sub.add_parser("bench", help="benchmark the simulator, training and inference (with anchors where installed)",
                       description="Time fixed, seeded workloads after a warm-up (compilation excluded): terrain noise, "
                                   "ray casting, the data stream and loader, training steps of the paper's model, and "
                                   "points -> map inference; with pyfastnoiselite and Open3D as anchors where installed "
                                   "(pip install -e .[bench]).")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout (progress goes to stderr)")
    _add_device(p)
    p.add_argument("--only", type=_only, default=None, metavar="NAMES",
                   help=f"comma-separated subset of {','.join(BENCH_NAMES)} (default: all)")
    p.add_argument("--quick", action="store_true", help="tiny workloads and fewer repeats: a smoke test, not a measurement")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    from ..bench import format_table, run_benchmarks

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    report = run_benchmarks(device=args.device, only=args.only, quick=args.quick, progress=progress)
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_table(report))
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
    from ..inference.predictor import load_predictor
    from ..plots.common import check_png_path
    from ..plots.usd import write_usd_figure
    from ..export.usd import check_usd_path, export_usd
    from ..sim import generate_batch, resolve_device

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
    sim.data.augment = False  # points and maps in the terrain's orientation
    if getattr(sim.data, "randomize", None) is not None:
        sim.data.randomize.enabled = False
    sim.validate()
    batch = generate_batch(1, sim, seed=args.seed, device=device)
    kwargs = {}
    if predictor is not None:
        predicted = predictor(batch.scan, batch.mask)
        kwargs = dict(reconstruction=(predicted[0] if isinstance(predicted, tuple) else predicted)[0, 0], target=batch.target[0, 0], reconstruction_cell=sim.data.map_cell)
    export_usd(out, batch.heights[0], sim.terrain.cell, points=batch.points[0] if args.with_points else None,
               sensor_z=float(batch.sensor_z[0]), **kwargs)
    print(out)
    if args.png is not None:
        print(write_usd_figure(out, args.png))
    return 0


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

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    manifest = write_dataset(args.out, args.count, sim, seed=args.seed, shard_size=args.shard_size, overwrite=args.overwrite,
                             with_points=args.with_points, device=args.device, progress=progress, workers=args.workers)
    if args.json:
        json.dump(manifest, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(f"wrote {manifest['count']} pairs in {len(manifest['shards'])} shards to {args.out}", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ evaluate
def _noise_levels(value: str) -> list[float]:
    try:
        levels = [float(s) for s in value.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid noise levels {value!r}: expected comma-separated numbers in [0, 1]") from None
    if not levels or any(not 0.0 <= x <= 1.0 for x in levels):
        raise argparse.ArgumentTypeError(f"invalid noise levels {value!r}: expected comma-separated numbers in [0, 1]")
    return levels


def _baseline_names(value: str) -> list[str]:
    from ..evaluation.baselines import BASELINES

    if value.strip() == "none":
        return []
    names = [s.strip() for s in value.split(",") if s.strip()]
    unknown = [n for n in names if n not in BASELINES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown baseline {', '.join(unknown) or value!r}: choose from {','.join(BASELINES)} or none")
    return names


def _int_at_least(minimum: int, what: str):
    """An argparse type: an integer >= ``minimum``, or an error naming ``what`` it is."""

    def parse(value: str) -> int:
        try:
            n = int(value)
        except ValueError:
            n = None
        if n is None or n < minimum:
            raise argparse.ArgumentTypeError(f"invalid {what} {value!r}: expected an integer >= {minimum}")
        return n

    return parse


_non_negative_int = _int_at_least(0, "count")
_positive_int = _int_at_least(1, "size")


def add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="score classical fills (and a trained model) in metres on fixed test sets",
                       description="Generate fixed test sets (seeds never used by training or validation) per terrain "
                                   "setting and noise level, fill them with the classical baselines and optionally a "
                                   "trained model, and report RMSE/MAE on unobserved, observed and in-range cells, "
                                   "obstacle IoU, pit recall and the time per map.")
    p.add_argument("--checkpoint", default=None, metavar="PATH", help="a training checkpoint (checkpoints/best.pt) or Reconstructor file: evaluate its model beside the baselines")
    p.add_argument("--pretrained", action="store_true", help="evaluate the model shipped in the package beside the baselines")
    _add_tta(p)
    p.add_argument("--robustness", action="store_true",
                   help="instead, score on settings outside the training ranges and on real DEM terrain (matplotlib's sample DEM)")
    p.add_argument("--settings", default="octave3,octave5,flat_cylinders,negative_obstacles", metavar="NAMES",
                   help="comma-separated terrain settings (conf/terrain) (default: octave3,octave5,flat_cylinders,negative_obstacles)")
    p.add_argument("--noise", type=_noise_levels, default=[0.0, 0.05, 0.10], metavar="LEVELS",
                   help="comma-separated image-noise levels, fractions of the height range (default: 0,0.05,0.1)")
    p.add_argument("--size", type=_positive_int, default=None, metavar="N", help="samples per setting (default: 64; 4 with --quick)")
    p.add_argument("--quick", action="store_true", help="a handful of samples per setting: a smoke test, not a measurement")
    p.add_argument("--baselines", type=_baseline_names, default=None, metavar="NAMES",
                   help="comma-separated subset of nearest,linear,biharmonic,telea,ns,plane, or none (default: all)")
    p.add_argument("--lidar", default="hdl32e", metavar="NAME", help="LIDAR preset (default: hdl32e)")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout (progress goes to stderr)")
    p.add_argument("--markdown", default=None, metavar="FILE", help="also write the tables as Markdown to FILE")
    p.add_argument("--figures", default=None, metavar="DIR", help="also write one PNG per setting into DIR (created if missing)")
    _add_device(p)
    p.set_defaults(func=cmd_evaluate)


def cmd_evaluate(args) -> int:
    from pathlib import Path

    from ..evaluation.baselines import BASELINES
    from ..evaluation import DEFAULT_SIZE, QUICK_SIZE, evaluate, format_markdown, format_table, json_ready
    from ..inference.predictor import load_predictor

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    size = args.size if args.size is not None else (QUICK_SIZE if args.quick else DEFAULT_SIZE)
    names = list(BASELINES) if args.baselines is None else args.baselines
    predictors = {n: BASELINES[n] for n in names}
    if args.markdown is not None and not Path(args.markdown).resolve().parent.is_dir():
        raise ValueError(f"--markdown {args.markdown!r}: the folder does not exist")
    model_info = None
    if args.checkpoint is not None or args.pretrained:
        predictor = load_predictor(args.checkpoint, device=args.device, tta=args.tta)
        model_info = predictor.info
        predictors["model"] = predictor
    if not predictors:
        raise ValueError("nothing to evaluate: --baselines none needs --checkpoint")
    if args.robustness:
        from ..evaluation.robustness import evaluate_robustness, robustness_markdown

        results = evaluate_robustness(predictors, size=size if args.size or args.quick else 32, device=args.device or "cpu", progress=progress)
        text = robustness_markdown(results)
        if args.markdown is not None:
            with atomic_open(Path(args.markdown), "w") as f:
                f.write(text)
        print(json.dumps(json_ready(results), indent=2, allow_nan=False) if args.json else text)
        return 0
    on_set = None
    if args.figures is not None:
        from ..plots.evaluation import figure_writer

        on_set = figure_writer(args.figures, progress=progress)
    results = evaluate(predictors, settings=args.settings, noise=args.noise, size=size, lidar=args.lidar,
                       device=args.device, on_set=on_set, progress=progress)
    if model_info is not None:
        results["model"] = model_info
    if args.markdown is not None:
        out = Path(args.markdown)
        with atomic_open(out, "w") as f:
            f.write(format_markdown(results))
        progress(f"wrote {out}")
    if args.json:
        json.dump(json_ready(results), sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(format_table(results))
    return 0


# ------------------------------------------------------------------------------ reconstruct
def _add_model(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default=None, metavar="PATH",
                   help="a Reconstructor file or training checkpoint (default: the model shipped in the package)")


def _add_tta(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-tta", dest="tta", action="store_false",
                   help="one prediction per map instead of the average over its 8 quarter turns and mirror images")


def add_reconstruct(sub) -> None:
    p = sub.add_parser("reconstruct", help="elevation map from a point-cloud file (.npy .ply .pcd .las .laz)",
                       description="Read a point cloud, move it into the sensor frame, project it into a map and fill "
                                   "it in with the model. Writes an .npz (height, mask, and uncertainty: each cell's standard "
                                   "deviation in metres, if the model predicts one) and a PNG preview.")
    p.add_argument("file", help="the point cloud (.npy (N,3), .ply, .pcd, .las, .laz)")
    p.add_argument("--out", default=None, metavar="OUT.npz", help="output (default: FILE with .npz); a PNG preview is written beside it")
    p.add_argument("--map-size", type=_positive_int, default=121, metavar="S", help="cells per side (default 121)")
    p.add_argument("--map-cell", type=float, default=0.25, metavar="M", help="cell size in metres (default 0.25)")
    p.add_argument("--transform", default=None, metavar="VALUES",
                   help="points -> sensor frame: 16 comma-separated values (a 4x4 matrix, row-major) or 6 (x,y,z,roll,pitch,yaw in m and degrees)")
    _add_model(p)
    _add_tta(p)
    _add_device(p)
    p.set_defaults(func=cmd_reconstruct)


def cmd_reconstruct(args) -> int:
    from pathlib import Path

    import numpy as np

    from ..inference.reconstructor import Reconstructor
    from ..plots.maps import save_map_preview
    from ..inference.pointclouds import apply_transform, read_point_cloud, transform_matrix

    source = Path(args.file)
    out = Path(args.out) if args.out else source.with_suffix(".npz")
    if out.suffix != ".npz":
        raise ValueError(f"--out {str(out)!r}: must end in .npz")
    if not out.resolve().parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder {str(out.resolve().parent)!r} does not exist")
    matrix = transform_matrix([float(v) for v in args.transform.split(",")]) if args.transform else None
    points = read_point_cloud(source)
    if matrix is not None:
        points = apply_transform(points, matrix)
    rec = Reconstructor.load(args.model, device=args.device, tta=args.tta)
    maps = rec.reconstruct_all(points, args.map_size, args.map_cell)
    with atomic_open(out) as f:
        np.savez_compressed(f, **maps, map_cell=np.float32(args.map_cell))
    png = out.with_suffix(".png")
    save_map_preview(maps["height"], maps["mask"], args.map_cell, png, title=source.name)
    print(json.dumps({"npz": str(out), "png": str(png), "points": int(len(points)), "observed_cells": int(maps["mask"].sum()),
                      "map_size": args.map_size, "map_cell": args.map_cell, "uncertainty": "uncertainty" in maps}))
    return 0


# ------------------------------------------------------------------------------ export-onnx
def add_export_onnx(sub) -> None:
    p = sub.add_parser("export-onnx", help="export the generator to ONNX, checked against torch with ONNX Runtime",
                       description="Export the generator (input 'condition' (B,C,S,S), output 'height' (B,1,S,S), and "
                                   "'log_variance' (B,1,S,S) if the model predicts its uncertainty) and "
                                   "check it against torch on generated scans; prints the largest difference and the "
                                   "latency of both.")
    p.add_argument("out", help="OUT.onnx")
    p.add_argument("--map-size", type=_positive_int, default=121, metavar="S", help="cells per side (fixed in the graph; default 121)")
    _add_model(p)
    p.set_defaults(func=cmd_export_onnx)


def cmd_export_onnx(args) -> int:
    from .. import generate_batch
    from ..inference.reconstructor import Reconstructor
    from ..inference.onnx import check_onnx, export_onnx

    rec = Reconstructor.load(args.model, device="cpu")
    path = export_onnx(rec.generator, args.out, rec.model_config.in_channels, args.map_size, uncertainty=rec.has_uncertainty)
    batch = generate_batch(4, {"data": {"map_size": args.map_size}}, seed=0, device="cpu")
    report = check_onnx(rec.generator, path, rec.condition(batch.scan, batch.mask), uncertainty=rec.has_uncertainty)
    report["onnx"] = str(path)
    print(json.dumps(report))
    if report["max_abs_diff"] > 1e-4:
        print(f"error: ONNX differs from torch by {report['max_abs_diff']:.2e} m (> 1e-4)", file=sys.stderr)
        return 1
    return 0


# ------------------------------------------------------------------------------ package-model
def add_package_model(sub) -> None:
    p = sub.add_parser("package-model", help="turn a training checkpoint into a small Reconstructor file",
                       description="Keep the generator only, in fp16, with its model config and the run config it was trained with.")
    p.add_argument("checkpoint", help="a training checkpoint (checkpoints/best.pt)")
    p.add_argument("--out", required=True, metavar="OUT.pt")
    p.add_argument("--calibrate", type=_non_negative_int, default=256, metavar="N",
                   help="fit the uncertainty's scale on N validation pairs of the run's own data settings "
                        "(default 256; 0 skips; models without an uncertainty head skip it)")
    _add_device(p)
    p.set_defaults(func=cmd_package_model)


def cmd_package_model(args) -> int:
    from pathlib import Path

    from ..inference.reconstructor import Reconstructor

    out = Path(args.out)
    if not out.resolve().parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder does not exist")
    rec = Reconstructor.load(args.checkpoint, device=args.device)
    if args.calibrate and rec.has_uncertainty:
        from ..evaluation.calibrate import fit_sigma_scale
        from ..sim.batch import as_sim_config

        run = rec.meta.get("config") or {}
        if not all(key in run for key in ("terrain", "lidar", "data")):
            raise ValueError(f"{args.checkpoint!r}: holds no run config to calibrate on (use --calibrate 0)")
        sim = as_sim_config({key: run[key] for key in ("terrain", "lidar", "data")})
        rec.meta["sigma_scale"] = fit_sigma_scale(rec, sim, args.calibrate, device=rec.device)
    rec.save(out)
    print(json.dumps({"out": str(out), "bytes": out.stat().st_size, "step": rec.meta.get("step"),
                      "sigma_scale": rec.meta.get("sigma_scale")}))
    return 0


# ------------------------------------------------------------------------------ train
def add_train(sub) -> None:
    sub.add_parser("train", help="train a model: Hydra overrides as for python train.py (warp-terrain train --help)",
                   description="Hydra overrides follow, e.g. warp-terrain train terrain=octave3 train.steps=500; "
                               "the same as python train.py in a source checkout.", add_help=False)


def run_train(args: list[str]) -> int:
    """``warp-terrain train OVERRIDES``: Hydra parses the rest of the command line."""
    from .train import main as train_main

    saved = sys.argv
    sys.argv = ["warp-terrain train", *args]
    try:
        train_main()
    finally:
        sys.argv = saved
    return 0


# ------------------------------------------------------------------------------ entry point
SUBCOMMANDS = (add_train, add_bench, add_preview, add_figures, add_export_usd, add_generate, add_evaluate, add_reconstruct, add_export_onnx,
               add_package_model)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warp-terrain",
        description="Simulated LIDAR terrains and their elevation maps: everyday commands.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad arguments)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "train":
        return run_train(argv[1:])
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help/--version (0) or a usage error (2), already printed
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    try:
        return int(args.func(args) or 0)
    except ValueError as e:
        message = " ".join(str(e).split()) or type(e).__name__
        print(f"error: {message}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
