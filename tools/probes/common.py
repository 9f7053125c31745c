"""What the probes share: run ``tools/real_ablation.py`` with each model's predictor wrapped so
that a probe's settings, parsed from the model's NAME, are in force while it predicts."""

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import real_ablation  # noqa: E402

from warp_terrain.inference.reconstructor import Reconstructor  # noqa: E402
from warp_terrain.inference.selfcheck import CANDIDATE_TENSIONS  # noqa: E402


def load_checked(path: str, tta: bool = True, self_check: bool = True) -> Reconstructor:
    """A checkpoint or Reconstructor file (``shipped``: the packaged one) checked as the shipped
    file is: reach, membrane, keep-far and sigma (with ``self_check=False``: not checked)."""
    rec = Reconstructor.load(None if path == "shipped" else path, device="cpu", tta=tta, self_check=self_check, check_reach=True,
                             check_sigma=True, check_keep_far=True)
    rec.check_tensions = CANDIDATE_TENSIONS
    return rec


def run(settings_of, active: dict) -> None:
    """``settings_of(name) -> dict``; ``active`` is cleared and filled with them around each call."""
    plain = real_ablation.models

    def models(args):
        out = {}
        for arg in args:
            name = arg.split("=", 1)[0]
            inner, settings = plain([arg])[name], settings_of(name)

            def predict(scan, mask, inner=inner, settings=settings):
                active.clear()
                active.update(settings)
                return inner(scan, mask)

            out[name] = predict
        return out

    real_ablation.models = models
    real_ablation.main()
