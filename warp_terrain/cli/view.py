"""``warp-terrain view``: a simulated terrain (and a model's reconstruction of it) or a reconstructed
map file as an interactive 3-D page in the browser (viser)."""

from __future__ import annotations

import sys
import time

from .args import _add_device, _add_tta, _positive_int


def _port(value: str) -> int:
    import argparse

    try:
        port = int(value)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"invalid port {value!r}: expected an integer in [0, 65535] (0: any free port)")
    return port


def add_view(sub) -> None:
    p = sub.add_parser("view", help="an interactive 3-D page: a simulated terrain, its scan and a model's reconstruction, or a map file",
                       description="Serve an interactive 3-D view (viser) and print its URL; runs until Ctrl-C. Without MAP: "
                                   "samples of a terrain setting from the simulator, side by side the input (scan image and "
                                   "LIDAR points), with --checkpoint or --pretrained the model's reconstruction, and the ground "
                                   "truth. With MAP (an .npz written by warp-terrain reconstruct): its observed cells and the "
                                   "reconstructed surface. The GUI colours the surfaces by height or uncertainty (or the "
                                   "error against the truth), toggles each layer and picks the sample.")
    p.add_argument("map", nargs="?", default=None, metavar="MAP.npz", help="a map written by warp-terrain reconstruct (instead of the simulator)")
    p.add_argument("--terrain", default=None, metavar="NAME",
                   help="terrain setting (octave3, octave5, flat_cylinders, negative_obstacles, ...) or a terrain .yaml "
                        "(default: octave5, or the model's terrain)")
    p.add_argument("--seed", type=int, default=None, help="sample seed (default: 0)")
    p.add_argument("--samples", type=_positive_int, default=None, metavar="K", help="samples to generate, picked with the GUI's slider (default: 4)")
    p.add_argument("--checkpoint", default=None, metavar="PATH", help="a training checkpoint or Reconstructor file: show its reconstruction")
    p.add_argument("--pretrained", action="store_true", help="show the reconstruction of the model shipped in the package")
    _add_tta(p)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default: 127.0.0.1, this machine only)")
    p.add_argument("--port", type=_port, default=8080, help="port to listen on (default: 8080, or the next free one; 0: any free port)")
    _add_device(p)
    p.set_defaults(func=cmd_view)


def _check_options(args) -> None:
    if args.checkpoint is not None and args.pretrained:
        raise ValueError(f"--checkpoint {args.checkpoint!r} and --pretrained name two models: give one")
    if args.map is not None:
        given = [name for name, value in (("--terrain", args.terrain), ("--seed", args.seed), ("--samples", args.samples),
                                          ("--checkpoint", args.checkpoint), ("--pretrained", args.pretrained or None))
                 if value is not None]
        if given:
            raise ValueError(f"{', '.join(given)}: the simulator's options; {args.map!r} is a map file, shown as it is")


def _samples(args) -> tuple[list, str]:
    """The views to serve and the viewer's title; every check before any work."""
    if args.map is not None:
        from ..plots.scene3d import load_map_file

        return [load_map_file(args.map)], f"map {args.map}"
    import copy

    from ..compose import load_terrain_setting
    from ..inference.predictor import load_predictor
    from ..plots.scene3d import simulated_samples
    from ..sim import resolve_device

    device = resolve_device(args.device)
    predictor = None
    if args.checkpoint is not None or args.pretrained:
        predictor = load_predictor(args.checkpoint, device, tta=args.tta)
        sim = copy.deepcopy(predictor.sim or load_terrain_setting("octave5"))
        if args.terrain is not None:
            sim.terrain = load_terrain_setting(args.terrain).terrain
    else:
        sim = load_terrain_setting(args.terrain or "octave5")
    count = 4 if args.samples is None else args.samples
    seed = 0 if args.seed is None else args.seed
    model = "" if predictor is None else f", model {'shipped' if args.pretrained else args.checkpoint}"
    print(f"view: generating {count} sample{'s' * (count > 1)} of {sim.terrain.name}{model} ...", file=sys.stderr, flush=True)
    return simulated_samples(sim, seed=seed, count=count, predictor=predictor, device=device), f"{sim.terrain.name}{model}"


def cmd_view(args) -> int:
    from ..plots.viewer import check_host, check_port, need_viser, start_viewer

    _check_options(args)
    need_viser()
    check_host(args.host)
    check_port(args.port)
    samples, title = _samples(args)
    viewer = start_viewer(samples, host=args.host, port=args.port, title=title)
    moved = f" (port {args.port} was busy)" if args.port not in (0, viewer.port) else ""
    print(f"view: listening on {viewer.url}{moved}; Ctrl-C to stop", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return 0
