"""Using a trained model: ``warp-terrain reconstruct`` (point-cloud files to maps: .npz, GeoTIFF, USD),
``warp-terrain export-onnx`` and ``warp-terrain package-model``."""

from __future__ import annotations

import json
import os
import sys

from .args import _add_device, _add_model, _add_tta, _non_negative_int, _positive_int


# ------------------------------------------------------------------------------ reconstruct
def add_reconstruct(sub) -> None:
    p = sub.add_parser("reconstruct", help="elevation maps from point-cloud files or a ROS bag (.npy .npz .bin .xyz .csv .txt .ply .pcd .las .laz .bag .mcap)",
                       description="Read point clouds, move them into the sensor frame, project each into a map and fill "
                                   "it in with the model. Writes per input a map (.npz: height, mask, and uncertainty, each "
                                   "cell's standard deviation in metres, if the model predicts one; or a GeoTIFF of those "
                                   "three bands), a PNG of the three beside it, and with --usd a USD stage of the points and "
                                   "the map. Existing files are never replaced without --overwrite. A ROS bag (.bag, a ROS 2 "
                                   "bag folder, .mcap) gives one map per PointCloud2 message (--topic, --every) into a folder.")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="point clouds: .npy/.npz ((N,3+) x, y, z first, extra columns ignored; .npz: a 'points' or 'xyz' array "
                        "or x, y, z arrays), KITTI .bin (float32 x, y, z, intensity), .xyz/.csv/.txt (an optional header "
                        "naming x, y, z), .ply, .pcd, .las, .laz; or one ROS bag: a ROS 1 .bag, a ROS 2 bag folder or an "
                        ".mcap file, one map per sensor_msgs/PointCloud2 message, written as STEM_INDEX.npz + .png into "
                        "the --out folder (default STEM_maps beside the bag)")
    p.add_argument("--out", default=None, metavar="OUT",
                   help="OUT.npz or OUT.tif/.tiff for one input (the format follows the suffix), or a folder (an existing "
                        "one, or a name ending in /) for one file set per input, named by its stem (stem_ext when two "
                        "inputs share a stem); default: beside each input. A PNG preview is written beside each map")
    p.add_argument("--format", choices=("npz", "tif"), default=None,
                   help="the map format when --out is a folder or not given (default npz)")
    p.add_argument("--crs", default=None, metavar="CRS",
                   help="GeoTIFF only: the coordinate reference system the points are in (EPSG:32633, WKT or PROJ); "
                        "the map lands where --transform's sensor pose puts it. Without it the GeoTIFF is in local metres, no CRS")
    p.add_argument("--usd", default=None, metavar="OUT.usda",
                   help="also write the points over the map and the reconstruction as a USD stage (.usda or .usdc); "
                        "with several inputs a folder, one STEM.usda per input")
    p.add_argument("--overwrite", action="store_true", help="replace output files that exist (default: refuse before any work)")
    p.add_argument("--map-size", type=_positive_int, default=None, metavar="S",
                   help="cells per side (default: the model's training maps, 121 for the shipped model)")
    p.add_argument("--map-cell", type=float, default=None, metavar="M",
                   help="cell size in metres (default: the model's training maps, 0.25 for the shipped model)")
    p.add_argument("--transform", default=None, metavar="VALUES",
                   help="points -> sensor frame: 16 comma-separated values (a 4x4 matrix, row-major) or 6 (x,y,z,roll,pitch,yaw in m and degrees)")
    p.add_argument("--topic", default=None, metavar="TOPIC",
                   help="ROS bags: the PointCloud2 topic (needed when the bag has several; they are listed if not given)")
    p.add_argument("--every", type=_positive_int, default=None, metavar="N",
                   help="ROS bags: one map per Nth PointCloud2 message, from the first (default 1: every message)")
    p.add_argument("--centre-cells", dest="centre_cells", action="store_true", default=None,
                   help="move each cell's height from its returns' mean position to the cell's centre by the thin plate's "
                        "gradient before the model sees it (2-5 %% lower error on clean smooth ground, level on noisy scans; "
                        "the checked sigma then too narrow; "
                        "default: as the model file says, off for the shipped model)")
    _add_model(p)
    _add_tta(p)
    _add_device(p)
    p.set_defaults(func=cmd_reconstruct)


def _is_folder_arg(value: str) -> bool:
    """A folder named on the command line: an existing one, or a name ending in a slash."""
    from pathlib import Path

    return value.endswith(("/", os.sep)) or Path(value).is_dir()


def _folder(value: str, option: str):
    """The folder ``value`` names, if it exists or its parent does (it is made once every check passed)."""
    from pathlib import Path

    folder = Path(value)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option} {value!r}: is a file, not a folder")
    if not folder.exists() and not folder.resolve().parent.is_dir():
        raise ValueError(f"{option} {value!r}: the folder {str(folder.resolve().parent)!r} does not exist")
    return folder


def _plan_outputs(sources, args) -> tuple[list[dict], list]:
    """Per input, the paths it will write (``map``, ``png``, ``usd`` or None) and the map
    ``format``, plus the folders to make; every conflict (two inputs on one name, an output over
    an input, an existing file without --overwrite, contradictory options) refused before any
    work, naming the file. Nothing is written here."""
    from pathlib import Path

    from ..export.usd import check_usd_path
    from ..inference.maps import map_format

    fmt = args.format
    folders_to_make = []
    if args.out is not None and not _is_folder_arg(args.out):  # one named file
        if len(sources) > 1:
            raise ValueError(f"--out {args.out!r}: names one file but {len(sources)} inputs were given; give a folder (--out DIR/)")
        try:
            fmt_out = map_format(args.out)
        except ValueError:
            raise ValueError(f"--out {args.out!r}: must end in .npz, .tif or .tiff, or name a folder") from None
        if fmt is not None and fmt != fmt_out:
            raise ValueError(f"--format {fmt} contradicts --out {args.out!r}; give one")
        fmt = fmt_out
        out = Path(args.out)
        if not out.resolve().parent.is_dir():
            raise ValueError(f"--out {args.out!r}: the folder {str(out.resolve().parent)!r} does not exist")
        named = [(out, out.with_suffix(".png"), out.stem)]
    else:  # one file set per input, named by its stem, in --out or beside the input
        fmt = fmt or "npz"
        out_folder = None if args.out is None else _folder(args.out, "--out")
        if out_folder is not None and not out_folder.exists():
            folders_to_make.append(out_folder)
        folders = [out_folder or source.parent for source in sources]
        inputs = {source.resolve() for source in sources}
        keys = [(str(folder.resolve()), source.stem.casefold()) for folder, source in zip(folders, sources)]
        named = []
        for i, (folder, source) in enumerate(zip(folders, sources)):
            shared = keys.count(keys[i]) > 1 or (folder / f"{source.stem}.{fmt}").resolve() in inputs
            name = f"{source.stem}_{source.suffix.lstrip('.').lower()}" if shared else source.stem
            named.append((folder / f"{name}.{fmt}", folder / f"{name}.png", name))
    usd_folder = None
    if args.usd is not None:
        if _is_folder_arg(args.usd):
            usd_folder = _folder(args.usd, "--usd")
            if not usd_folder.exists():
                folders_to_make.append(usd_folder)
        elif len(sources) > 1:
            raise ValueError(f"--usd {args.usd!r}: names one stage but {len(sources)} inputs were given; give a folder (--usd DIR/)")
        else:
            try:
                check_usd_path(args.usd)
            except ValueError as err:
                raise ValueError(f"--usd {str(err).removeprefix('path=')}") from None
    if args.crs is not None and fmt != "tif":
        raise ValueError(f"--crs {args.crs!r}: only a GeoTIFF carries a CRS; write --out NAME.tif or --format tif")
    plans = []
    for source, (map_path, png, name) in zip(sources, named):
        usd = None if args.usd is None else (usd_folder / f"{name}.usda" if usd_folder is not None else Path(args.usd))
        plans.append({"source": source, "format": fmt, "map": map_path, "png": png, "usd": usd})
    inputs = {source.resolve(): source for source in sources}
    seen: dict = {}
    for plan in plans:
        for path in (plan["map"], plan["png"], plan["usd"]):
            if path is None:
                continue
            real = path.resolve()
            if real in inputs:
                raise ValueError(f"{str(path)!r}: the output would overwrite the input {str(inputs[real])!r}; give --out")
            if real in seen:
                raise ValueError(f"{str(path)!r}: both {str(seen[real])!r} and {str(plan['source'])!r} would write it; "
                                 "rename one or run them separately")
            seen[real] = plan["source"]
            if path.exists() and not args.overwrite:
                raise ValueError(f"{str(path)!r}: exists; pass --overwrite to replace it")
    return plans, folders_to_make


def cmd_reconstruct(args) -> int:
    from pathlib import Path

    from ..core.geometry import MapGeometry
    from ..export.usd import export_reconstruction
    from ..inference.bags import is_bag
    from ..inference.maps import check_crs, need_rasterio, sensor_pose, write_map
    from ..inference.pointclouds import READERS, apply_transform, read_point_cloud, transform_matrix
    from ..inference.reconstructor import Reconstructor
    from ..plots.maps import save_map_preview
    from .bags import reconstruct_bag

    sources = [Path(f) for f in args.files]
    if any(is_bag(source) for source in sources):  # one map per message into a folder: cli/bags.py
        return reconstruct_bag(args, sources, transform_matrix([float(v) for v in args.transform.split(",")]) if args.transform else None)
    if args.topic is not None or args.every is not None:
        raise ValueError("--topic and --every read ROS bags; the inputs are point-cloud files")
    for source in sources:  # before --out, which defaults to names beside them
        if not source.is_file():
            raise ValueError(f"{str(source)!r}: no such file")
        if source.suffix.lower() not in READERS:
            raise ValueError(f"{str(source)!r}: unsupported point-cloud format {source.suffix or '(none)'!r}; use one of {', '.join(sorted(READERS))}")
    matrix = transform_matrix([float(v) for v in args.transform.split(",")]) if args.transform else None
    plans, folders_to_make = _plan_outputs(sources, args)
    crs = None
    if plans[0]["format"] == "tif":
        need_rasterio()
        try:
            crs = check_crs(args.crs)
        except ValueError as err:
            raise ValueError(f"--{err}") from None
        if matrix is not None:
            try:
                sensor_pose(matrix)
            except ValueError as err:
                raise ValueError(f"--transform {args.transform!r}: {str(err).removeprefix('transform: ')}") from None
    rec = Reconstructor.load(args.model, device=args.device, tta=args.tta, centre_cells=args.centre_cells)
    geometry = MapGeometry(*rec.resolve_geometry(args.map_size, args.map_cell))
    for folder in folders_to_make:  # every check passed: a refused run leaves no folder
        folder.mkdir(exist_ok=True)
    for plan in plans:
        source = plan["source"]
        points = read_point_cloud(source)
        if matrix is not None:
            points = apply_transform(points, matrix)
        maps = rec.reconstruct_all(points, geometry.size, geometry.cell)
        if plan["format"] == "tif":
            write_map(plan["map"], maps, geometry, transform=matrix, crs=crs)
        else:
            write_map(plan["map"], maps, geometry)
        save_map_preview(maps["height"], maps["mask"], geometry.cell, plan["png"], title=source.name, uncertainty=maps.get("uncertainty"))
        if plan["usd"] is not None:
            export_reconstruction(plan["usd"], maps["height"], geometry.cell, points, mask=maps["mask"], uncertainty=maps.get("uncertainty"))
        print(json.dumps({"input": str(source), "map": str(plan["map"]), "format": plan["format"], "png": str(plan["png"]),
                          "usd": None if plan["usd"] is None else str(plan["usd"]), "points": int(len(points)),
                          "observed_cells": int(maps["mask"].sum()), "map_size": geometry.size, "map_cell": geometry.cell,
                          "uncertainty": "uncertainty" in maps, "crs": None if crs is None else crs.to_string()}), flush=True)
    return 0

# ------------------------------------------------------------------------------ export-onnx
def add_export_onnx(sub) -> None:
    p = sub.add_parser("export-onnx", help="export the generator to ONNX, checked against torch with ONNX Runtime",
                       description="Export the generator (input 'condition' (B,C,S,S), output 'height' (B,1,S,S), and "
                                   "'log_variance' (B,1,S,S) if the model predicts its uncertainty) and "
                                   "check it against torch on generated scans; prints the largest difference per output "
                                   "and the latency of both, and exits 1 if an output differs beyond its tolerance "
                                   "(height 1 mm, log-variance 0.01: the float32 solve of the base fill rounds "
                                   "differently in the two runtimes).")
    p.add_argument("out", help="OUT.onnx")
    p.add_argument("--map-size", type=_positive_int, default=None, metavar="S",
                   help="cells per side, fixed in the graph (default: the model's training maps, 121 for the shipped model)")
    _add_model(p)
    p.set_defaults(func=cmd_export_onnx)


def cmd_export_onnx(args) -> int:
    from ..inference.onnx import PARITY_TOLERANCE, check_onnx, export_onnx
    from ..inference.reconstructor import Reconstructor
    from ..sim import generate_batch

    rec = Reconstructor.load(args.model, device="cpu")
    map_size = rec.resolve_geometry(args.map_size, None)[0]
    path = export_onnx(rec.generator, args.out, rec.model_config.in_channels, map_size, uncertainty=rec.has_uncertainty)
    batch = generate_batch(4, {"data": {"map_size": map_size}}, seed=0, device="cpu")
    report = check_onnx(rec.generator, path, rec.condition(batch.scan, batch.mask), uncertainty=rec.has_uncertainty)
    report["onnx"] = str(path)
    print(json.dumps(report))
    if report["beyond_tolerance"]:
        units = {"height": "m", "log_variance": "log m^2"}
        for name in report["beyond_tolerance"]:
            print(f"error: ONNX's {name} differs from torch's by {report['max_abs_diff_by_output'][name]:.2e} {units[name]} "
                  f"(tolerance {PARITY_TOLERANCE[name]:g}); the file {path} is written but does not match", file=sys.stderr)
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
    p.add_argument("--self-check", action="store_true",
                   help="the file's maps are checked on their own scans by default (Reconstructor self_check; fill-residual models only)")
    p.add_argument("--check-reach", action="store_true",
                   help="with --self-check: the check's weight holds near the scan only; far from it the weight measured "
                        "on the scan's outermost observed cells, hidden (inference/selfcheck.py)")
    p.add_argument("--check-sigma", action="store_true",
                   help="with --self-check: each map's sigma is scaled on the check's own cells, so that 68 %% of their "
                        "errors lie within 1 sigma (inference/selfcheck.py sigma_factor); with --calibrate, the factor "
                        "of the maps the check cannot resolve (noisy scans) is fitted on such maps of the same pairs")
    p.add_argument("--check-membrane", action="store_true",
                   help="with --self-check: the check also weighs the membrane (Laplace interpolation) beside the thin plate")
    p.add_argument("--check-keep-far", action="store_true",
                   help="with --check-reach: far from the scan the net's correction is kept whole, not weighed on the "
                        "outer cells (they lie next to kept ones, where the net errs most)")
    p.add_argument("--check-cycles", type=_non_negative_int, default=0, metavar="N",
                   help="with --self-check: N multigrid V-cycles on the thin plates the check weighs, after the "
                        "cascade (the cascade stops short in the wide gaps of sparse scans; default 0)")
    p.add_argument("--check-keep-shadows", action="store_true",
                   help="with --self-check: the net's correction is kept whole in the scan's shadows (unobserved cells "
                        "under the sensor's line of sight over the observed ones), unless the check's own cells refute "
                        "the scan's horizon (inference/shadows.py)")
    p.add_argument("--check-keep-large", action="store_true",
                   help="with --self-check: a correction of an obstacle's size (0.3 m, up or down) is kept whole on the "
                        "unobserved cells (a pit, an obstacle's hidden side), unless the check's hidden cells carry such "
                        "corrections and so measure them (inference/selfcheck.py)")
    p.add_argument("--observed-bound-noise", type=float, default=None, metavar="K",
                   help="widen the generator's bound on observed cells to K times each scan's own noise "
                        "(model.observed_bound_noise; it holds no weight; default: as the checkpoint's model)")
    _add_device(p)
    p.set_defaults(func=cmd_package_model)


def cmd_package_model(args) -> int:
    from pathlib import Path

    from ..evaluation.calibrate import package_model

    out = Path(args.out)
    if not out.resolve().parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder does not exist")
    print(json.dumps(package_model(args.checkpoint, out, calibrate=args.calibrate, device=args.device, self_check=args.self_check,
                                   check_reach=args.check_reach, check_sigma=args.check_sigma,
                                   check_membrane=args.check_membrane, check_keep_far=args.check_keep_far,
                                   observed_bound_noise=args.observed_bound_noise, check_cycles=args.check_cycles,
                                   check_keep_shadows=args.check_keep_shadows, check_keep_large=args.check_keep_large)))
    return 0
