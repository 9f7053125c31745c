"""``warp-terrain evaluate``: classical fills (and a trained model) scored in metres on fixed test sets."""

from __future__ import annotations

import json
import sys

from ..core.atomic import atomic_open
from .args import _add_device, _add_self_check, _add_tta, _baseline_names, _noise_levels, _positive_int
from .progress import _add_quiet, reporters


def add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="score classical fills (and a trained model) in metres on fixed test sets",
                       description="Generate fixed test sets (seeds never used by training or validation) per terrain "
                                   "setting and noise level, fill them with the classical baselines and optionally a "
                                   "trained model, and report RMSE/MAE on unobserved, observed and in-range cells, "
                                   "obstacle IoU, pit recall and the time per map.")
    p.add_argument("--checkpoint", default=None, metavar="PATH", help="a training checkpoint (checkpoints/best.pt) or Reconstructor file: evaluate its model beside the baselines")
    p.add_argument("--pretrained", action="store_true", help="evaluate the model shipped in the package beside the baselines")
    _add_tta(p)
    _add_self_check(p)
    p.add_argument("--robustness", action="store_true",
                   help="instead, score on settings outside the training ranges and on real DEM terrain (matplotlib's sample DEM)")
    p.add_argument("--real", action="store_true",
                   help="instead, the real-data suite: real DEM windows (true scale and rescaled), real LIDAR scans with "
                        "20%% of their observed cells hidden, and the synthetic ranges' edges; needs `make real-data`")
    p.add_argument("--real-data", default=None, metavar="DIR",
                   help="the folder `make real-data` wrote (default: $WARP_TERRAIN_REAL_DATA or ./real_data)")
    p.add_argument("--repeats", type=_positive_int, default=3, metavar="K", help="--real: hidden-cell draws per real scan (default: 3)")
    p.add_argument("--settings", default="octave3,octave5,flat_cylinders,negative_obstacles", metavar="NAMES",
                   help="comma-separated terrain settings (conf/terrain) (default: octave3,octave5,flat_cylinders,negative_obstacles)")
    p.add_argument("--noise", type=_noise_levels, default=[0.0, 0.05, 0.10], metavar="LEVELS",
                   help="comma-separated image-noise levels, fractions of the height range (default: 0,0.05,0.1)")
    p.add_argument("--size", type=_positive_int, default=None, metavar="N", help="samples per setting (default: 64; 4 with --quick)")
    p.add_argument("--quick", action="store_true", help="a handful of samples per setting: a smoke test, not a measurement")
    p.add_argument("--baselines", type=_baseline_names, default=None, metavar="NAMES",
                   help="comma-separated subset of nearest,linear,biharmonic,harmonic,telea,ns,plane, or none (default: all)")
    p.add_argument("--lidar", default="hdl32e", metavar="NAME", help="LIDAR preset (default: hdl32e)")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout (progress goes to stderr)")
    p.add_argument("--markdown", default=None, metavar="FILE", help="also write the tables as Markdown to FILE")
    p.add_argument("--figures", default=None, metavar="DIR", help="also write one PNG per setting into DIR (created if missing)")
    _add_quiet(p)
    _add_device(p)
    p.set_defaults(func=cmd_evaluate)


def cmd_evaluate(args) -> int:
    from pathlib import Path

    from ..evaluation import DEFAULT_SIZE, QUICK_SIZE, evaluate, format_markdown, format_table, json_ready
    from ..evaluation.baselines import BASELINES
    from ..inference.predictor import load_predictor

    progress, track = reporters(args.quiet, "set")
    size = args.size if args.size is not None else (QUICK_SIZE if args.quick else DEFAULT_SIZE)
    names = list(BASELINES) if args.baselines is None else args.baselines
    predictors = {n: BASELINES[n] for n in names}
    if args.markdown is not None and not Path(args.markdown).resolve().parent.is_dir():
        raise ValueError(f"--markdown {args.markdown!r}: the folder does not exist")
    model_info = None
    if args.checkpoint is not None and args.pretrained:
        raise ValueError(f"--checkpoint {args.checkpoint!r} and --pretrained name two models: give one")
    if args.checkpoint is not None or args.pretrained:
        predictor = load_predictor(args.checkpoint, device=args.device, tta=args.tta, self_check=args.self_check)
        model_info = predictor.info
        predictors["model"] = predictor
    if not predictors:
        raise ValueError("nothing to evaluate: --baselines none needs --checkpoint")
    if args.real and args.robustness:
        raise ValueError("--real and --robustness are two different suites: give one")
    if args.real:
        from ..evaluation.real import evaluate_real, real_markdown

        results = evaluate_real(predictors, data_dir=args.real_data, size=size if args.size or args.quick else 32,
                                repeats=args.repeats, device=args.device or "cpu", progress=progress, track=track)
        if model_info is not None:
            results["model"] = model_info
        text = real_markdown(results)
        if args.markdown is not None:
            with atomic_open(Path(args.markdown), "w") as f:
                f.write(text)
        print(json.dumps(json_ready(results), indent=2, allow_nan=False) if args.json else text)
        return 0
    if args.robustness:
        from ..evaluation.robustness import evaluate_robustness, robustness_markdown

        results = evaluate_robustness(predictors, size=size if args.size or args.quick else 32, device=args.device or "cpu", progress=progress, track=track)
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
                       device=args.device, on_set=on_set, progress=progress, track=track)
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
