"""The real suite and the synthetic settings for the classical fills, the torch fills and models.

usage: python tools/real_ablation.py [NAME=MODEL ...]
  MODEL: a checkpoint, a Reconstructor file, or `shipped`; NAME containing `_check` turns the
  self-check on, `_reach` / `_noreach` the check's reach on / off (else as the file says), `_notta` the 8-orientation average off. Writes tools/real_ablation_<names>.json
  beside printing each figure (needs `make real-data`; README, "Transfer to real ground").
"""

import json
import os
import sys

import torch

from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.evaluation.metrics import masked_rmse
from warp_terrain.evaluation.real import evaluate_real
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.predictor import load_predictor
from warp_terrain.models.biharmonic import biharmonic_fill
from warp_terrain.models.fill import push_pull_fill

torch.set_num_threads(int(os.environ.get("THREADS", "1")))
predictors = dict(BASELINES)
predictors["push_pull"] = push_pull_fill
predictors["bh_torch"] = biharmonic_fill
for arg in sys.argv[1:]:
    name, path = arg.split("=", 1)
    predictors[name] = load_predictor(None if path == "shipped" else path, device="cpu", tta="_notta" not in name, self_check="_check" in name,
                                      check_reach=False if "_noreach" in name else (True if "_reach" in name else None))
real = evaluate_real(predictors, size=32, repeats=3, device="cpu", progress=lambda line: print(line, flush=True))
synthetic = {}
for setting in ("octave5", "octave3", "flat_cylinders", "negative_obstacles"):
    for noise in (0.0, 0.1):
        ts = make_eval_set(setting, noise, size=32, device="cpu")
        unobserved = ts.mask < 0.5
        row = {}
        for name, f in predictors.items():
            out = f(ts.scan, ts.mask)
            out = out[0] if isinstance(out, tuple) else out
            row[name] = masked_rmse(out.float(), ts.target, unobserved)
        synthetic[f"{setting}/{noise}"] = row
        print(setting, noise, {k: round(v, 4) for k, v in row.items()}, flush=True)
out = os.path.join(os.path.dirname(__file__), "real_ablation_" + "_".join(a.split("=")[0] for a in sys.argv[1:]) + ".json")
with open(out, "w") as f:
    json.dump({"real": real, "synthetic": synthetic}, f)
