"""What the probes share: run ``tools/real_ablation.py`` with each model's predictor wrapped so
that a probe's settings, parsed from the model's NAME, are in force while it predicts."""

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import real_ablation  # noqa: E402


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
