"""The ``torch.compile`` child of TRAIN, started by :mod:`.train` in a fresh interpreter as
``python -m warp_terrain.bench.compiled_child SPEC_JSON`` (SPEC: device, batch, repeats,
threads, model config): the fixed-batch steps with ``torch.compile``'d nets. Prints one JSON
line when ready to compile, one when compiled (with the first two steps' seconds) and one
with the timings when done."""

from __future__ import annotations

import json
import sys
import time

import torch

from ..models import ModelConfig
from .harness import summarize, sync_device, time_calls
from .train import build_train_model, fixed_pair, train_inputs


def _emit(event: str, **values) -> None:
    print(json.dumps({"event": event, **values}), flush=True)


def main(argv: list[str] | None = None) -> int:
    """Run the compiled steps of the spec in ``argv[0]`` (default: the command line's)."""
    spec = json.loads((sys.argv[1:] if argv is None else argv)[0])
    device, batch, repeats = spec["device"], int(spec["batch"]), int(spec["repeats"])
    torch.set_num_threads(int(spec["threads"]))
    model_cfg = ModelConfig(**spec["model"])
    model = build_train_model(model_cfg, device)
    model.netG = torch.compile(model.netG)
    model.netD = torch.compile(model.netD)
    x, y = train_inputs(fixed_pair(batch, device), model_cfg.in_channels, device)

    def step():
        model.set_input(x, y)
        model.optimize_parameters()

    _emit("ready")
    t0 = time.perf_counter()
    step()  # compiles G's forward and backward and D's two variants (D trained, then frozen)
    step()  # anything compiled late (e.g. guards on the second call)
    sync_device(device)
    _emit("compiled", first_two_steps_s=time.perf_counter() - t0)
    _emit("done", **summarize(time_calls(step, device, repeats, warmup=0)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
