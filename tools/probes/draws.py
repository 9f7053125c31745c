"""How much the self-check's own draw of hidden cells moves a model's scores, and what averaging
draws buys.

The check hides a fixed random fifth of each map's observed cells (``selfcheck.hidden_cells``,
seed ``CHECK_SEED``); another seed hides other cells and gives the map another weight. NAME
tokens: ``_seedN`` checks with seed N instead (a single draw); ``_draws K`` (``_draws2``,
``_draws3``) averages the checked maps and sigmas of K draws (seeds ``CHECK_SEED``,
``CHECK_SEED + 1``, ...): K thinned passes of the model instead of one.

usage: THREADS=1 python tools/probes/draws.py --fills-cache outputs/fills_cache.json \
           S1_check_reach_keepfar_sigma_membrane_seed1=shipped D2_check_reach_keepfar_sigma_membrane_draws2=shipped
"""

import re

import common  # noqa: F401  (puts tools/ on the path)
import real_ablation  # noqa: E402
import torch

import warp_terrain.inference.selfcheck as check  # noqa: E402

PROBE: dict = {}
#: the shipped draw, kept before ``check.hidden_cells`` is replaced
PLAIN_HIDDEN = check.hidden_cells


def hidden_cells(mask: torch.Tensor, share: float = check.CHECK_SHARE, seed: int = check.CHECK_SEED) -> torch.Tensor:
    return PLAIN_HIDDEN(mask, share, PROBE.get("seed", seed))


def settings_of(name: str) -> dict:
    seed = re.search(r"_seed(\d+)", name)
    draws = re.search(r"_draws(\d+)", name)
    return {"seed": int(seed[1]) if seed else check.CHECK_SEED, "draws": int(draws[1]) if draws else 1}


def models(args) -> dict:
    out = {}
    for arg in args:
        name = arg.split("=", 1)[0]
        inner, settings = PLAIN_MODELS([arg])[name], settings_of(name)

        def predict(scan, mask, inner=inner, settings=settings):
            outputs = []
            for k in range(settings["draws"]):
                PROBE["seed"] = settings["seed"] + k
                outputs.append(inner(scan, mask))
            PROBE.clear()
            if isinstance(outputs[0], tuple):
                return tuple(torch.stack(parts).mean(dim=0) for parts in zip(*outputs))
            return torch.stack(outputs).mean(dim=0)

        out[name] = predict
    return out


if __name__ == "__main__":
    check.hidden_cells = hidden_cells  # what selfcheck.check_cells draws
    PLAIN_MODELS = real_ablation.models
    real_ablation.models = models
    real_ablation.main()
