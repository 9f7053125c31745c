"""The real suite and the synthetic settings for the classical fills, the torch fills and models.

usage: python tools/real_ablation.py [--fills-cache FILE] [--size N] NAME=MODEL ...
       python tools/real_ablation.py --report tools/real_ablation_<names>.json
  MODEL: a checkpoint, a Reconstructor file, or `shipped`; NAME containing `_check` turns the
  self-check on, `_reach` / `_noreach` the check's reach on / off, `_sigma` / `_nosigma` the
  check's per-map sigma on / off (else as the file says), `_notta` the 8-orientation average
  off, `_nomembrane` the check's membrane candidate off (the thin plate alone beside the base
  fill), `_keepfar` / `_nokeepfar` the check's correction kept whole far from the scan on / off
  (else as the file says), `_cyclesN` N multigrid V-cycles on the check's thin plates (else as the file
  says), `_shadows` / `_noshadows` the correction kept whole in the scan's shadows on / off (else as
  the file says), `_large` / `_nolarge` large corrections kept whole unless the check measures them on / off (else as
  the file says). The classical fills are scored too; with --fills-cache their scores are read from FILE
  when it exists (the fills are deterministic: same seeds, same maps) and written to it when
  not. Writes tools/real_ablation_<names>.json and prints, per family, each model's RMSE over
  the best classical fill's and its share of scored cells within 1 sigma, then one markdown
  table row per model (needs `make real-data`; README, "Transfer to real ground").
"""

import argparse
import hashlib
import json
import os
import re

import torch

from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.evaluation.metrics import masked_rmse
from warp_terrain.evaluation.real import evaluate_real, headline
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.predictor import reconstructor_predictor
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.inference.selfcheck import CANDIDATE_TENSIONS, THIN_PLATE_ONLY
from warp_terrain.models.biharmonic import biharmonic_fill
from warp_terrain.models.fill import push_pull_fill

SETTINGS = ("octave5", "octave3", "flat_cylinders", "negative_obstacles")
NOISES = (0.0, 0.1)
#: the torch fills scored beside the classical ones (``BASELINES``)
TORCH_FILLS = {"push_pull": push_pull_fill, "bh_torch": biharmonic_fill}


def flag(name: str, key: str):
    return False if f"_no{key}" in name else (True if f"_{key}" in name else None)


def cycles(name: str) -> int | None:
    found = re.search(r"_cycles(\d+)", name)
    return None if found is None else int(found.group(1))


def models(args) -> dict:
    out = {}
    for arg in args:
        name, path = arg.split("=", 1)
        file = None if path == "shipped" else path
        rec = Reconstructor.load(file, device="cpu", tta="_notta" not in name, self_check="_check" in name,
                                 check_reach=flag(name, "reach"), check_sigma=flag(name, "sigma"),
                                 check_keep_far=flag(name, "keepfar"), check_cycles=cycles(name),
                                 check_keep_shadows=flag(name, "shadows"), check_keep_large=flag(name, "large"))
        if flag(name, "membrane") is not None:
            rec.check_tensions = CANDIDATE_TENSIONS if flag(name, "membrane") else THIN_PLATE_ONLY
        out[name] = reconstructor_predictor(rec, 16, file)
    return out


def synthetic_scores(predictors: dict, size: int) -> dict:
    rows = {}
    for setting in SETTINGS:
        for noise in NOISES:
            ts = make_eval_set(setting, noise, size=size, device="cpu")
            unobserved = ts.mask < 0.5
            row = {}
            for name, f in predictors.items():
                out = f(ts.scan, ts.mask)
                pred, sigma = out if isinstance(out, tuple) else (out, None)
                row[name] = {"rmse_unobserved": masked_rmse(pred.float(), ts.target, unobserved)}
                if sigma is not None:
                    row[name]["within_1sigma"] = float(((pred - ts.target).abs() <= sigma)[unobserved].float().mean())
            rows[f"{setting}/{noise}"] = row
            print(setting, noise, {k: round(v["rmse_unobserved"], 4) for k, v in row.items()}, flush=True)
    return rows


def report(real: dict, synthetic: dict, nets: list) -> None:
    """Print, per family, each model's RMSE over the best classical fill's (and its share within 1
    sigma), then one markdown table row per model."""
    rows = [(e["family"], {m: v[headline(e)] for m, v in e["metrics"].items()}, {m: v.get("within_1sigma") for m, v in e["metrics"].items()})
            for e in real["families"]]
    rows += [(key, {m: v["rmse_unobserved"] for m, v in row.items()}, {m: v.get("within_1sigma") for m, v in row.items()})
             for key, row in synthetic.items()]
    print("\nmodel / best classical fill (within 1 sigma)")
    ratios = {m: [] for m in nets}
    for family, rmse, within in rows:
        best = min((m for m in rmse if m in BASELINES), key=rmse.get)
        for m in nets:
            ratios[m].append(rmse[m] / rmse[best])
        cells = [f"{m} {ratios[m][-1]:.2f}" + (f" ({100 * within[m]:.0f} %)" if within.get(m) is not None else "") for m in nets]
        print(f"{family[:36]:36s} best {best:10s} {rmse[best]:.4f}  " + "  ".join(cells))
    print("\nas table rows (README, \"Transfer to real ground\": the families in the order above)")
    for m in nets:
        print(f"| {m} | " + " | ".join(f"{r:.2f}" for r in ratios[m]) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fills-cache", help="JSON of the classical fills' scores: read if it exists, else written")
    parser.add_argument("--size", type=int, default=32, help="maps per family and per synthetic setting")
    parser.add_argument("--report", metavar="JSON", help="print the tables of a run's tools/real_ablation_<names>.json again, and stop")
    parser.add_argument("models", nargs="*", help="NAME=MODEL")
    args = parser.parse_args()
    fills = {**BASELINES, **TORCH_FILLS}
    if args.report:
        with open(args.report) as f:
            saved = json.load(f)
        report(saved["real"], saved["synthetic"], [m for m in saved["real"]["methods"] if m not in fills])
        return
    torch.set_num_threads(int(os.environ.get("THREADS", "1")))
    say = lambda line: print(line, flush=True)  # noqa: E731
    nets = models(args.models)
    if args.fills_cache and os.path.exists(args.fills_cache):
        with open(args.fills_cache) as f:
            cached = json.load(f)
        real = evaluate_real(nets, size=args.size, repeats=3, device="cpu", progress=say)
        for entry in real["families"]:
            entry["metrics"] = {**cached["real"][entry["family"]], **entry["metrics"]}
        real["methods"] = list(fills) + list(nets)
        synthetic = synthetic_scores(nets, args.size)
        for key, row in synthetic.items():
            synthetic[key] = {**cached["synthetic"][key], **row}
    else:
        real = evaluate_real({**fills, **nets}, size=args.size, repeats=3, device="cpu", progress=say)
        synthetic = synthetic_scores({**fills, **nets}, args.size)
        if args.fills_cache:
            with open(args.fills_cache, "w") as f:
                json.dump({"real": {e["family"]: {k: v for k, v in e["metrics"].items() if k in fills} for e in real["families"]},
                           "synthetic": {k: {m: v for m, v in row.items() if m in fills} for k, row in synthetic.items()}}, f)
    names = "_".join(a.split("=")[0] for a in args.models) or "fills"
    if len(names) > 120:  # a file name has at most 255 bytes: long lists keep their start and a digest
        names = f"{names[:100]}_{hashlib.sha1(names.encode()).hexdigest()[:12]}"
    with open(os.path.join(os.path.dirname(__file__), f"real_ablation_{names}.json"), "w") as f:
        json.dump({"real": real, "synthetic": synthetic}, f)
    report(real, synthetic, list(nets))


if __name__ == "__main__":
    main()
