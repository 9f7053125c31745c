"""Average a fine-tuned generator's weights with those it started from (weight-space ensembling,
as WiSE-FT does for fine-tuned classifiers: Wortsman et al., "Robust fine-tuning of zero-shot
models", CVPR 2022). A fine-tune gains where its world moved and drifts elsewhere; the average
of the two nets often keeps most of the gain and little of the drift (docs/transfer.md, stop 35).

usage: python tools/average_weights.py FINETUNED START --alpha 0.5 --out outputs/soup.pt

FINETUNED: a training checkpoint (its structure, config and step are kept); START: a checkpoint
or a Reconstructor file (``pretrained``: the packaged one). The result is FINETUNED with its
generator's floating-point tensors replaced by ``alpha * finetuned + (1 - alpha) * start``
(integer buffers, such as batch-norm counters, kept from FINETUNED); both nets must have the
same tensors and shapes. Written atomically; load it like any checkpoint.
"""

import argparse

from warp_terrain.core.torchfile import atomic_save, load_checkpoint
from warp_terrain.inference.reconstructor import pretrained_path


def generator_state(blob: dict, path: str) -> dict:
    """The generator's state dict of a training checkpoint or a Reconstructor file."""
    if "netG" in blob:
        return blob["netG"]
    if isinstance(blob.get("model"), dict) and "netG" in blob["model"]:
        return blob["model"]["netG"]
    raise ValueError(f"{path}: neither a training checkpoint nor a Reconstructor file (no generator weights)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("finetuned", help="the fine-tuned training checkpoint")
    parser.add_argument("start", help="the weights it started from: a checkpoint, a Reconstructor file or `pretrained`")
    parser.add_argument("--alpha", type=float, default=0.5, help="the fine-tuned net's share, in [0, 1]")
    parser.add_argument("--out", required=True, help="where to write the averaged checkpoint")
    args = parser.parse_args()
    if not 0.0 <= args.alpha <= 1.0:
        parser.error(f"--alpha={args.alpha}: must lie in [0, 1]")
    start_path = str(pretrained_path()) if args.start == "pretrained" else args.start
    tuned_blob, start_blob = load_checkpoint(args.finetuned), load_checkpoint(start_path)
    if not (isinstance(tuned_blob.get("model"), dict) and "netG" in tuned_blob["model"]):
        raise SystemExit(f"{args.finetuned}: not a training checkpoint (no model.netG)")
    tuned, start = tuned_blob["model"]["netG"], generator_state(start_blob, start_path)
    if set(tuned) != set(start):
        raise SystemExit(f"the two nets differ in their tensors: {sorted(set(tuned) ^ set(start))[:5]} ...")
    for key, value in tuned.items():
        if value.shape != start[key].shape:
            raise SystemExit(f"{key}: shape {tuple(value.shape)} in {args.finetuned}, {tuple(start[key].shape)} in {start_path}")
    tuned_blob["model"]["netG"] = {
        key: (args.alpha * value.float() + (1.0 - args.alpha) * start[key].float()).to(value.dtype) if value.is_floating_point() else value
        for key, value in tuned.items()
    }
    atomic_save(tuned_blob, args.out)
    print(f"wrote {args.out}: {args.alpha:g} x {args.finetuned} + {1 - args.alpha:g} x {start_path}")


if __name__ == "__main__":
    main()
