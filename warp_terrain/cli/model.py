"""Using a trained model: ``warp-terrain reconstruct`` (a point-cloud file to a map),
``warp-terrain export-onnx`` and ``warp-terrain package-model``."""

from __future__ import annotations

import json
import sys

from .args import _add_device, _add_model, _add_tta, _non_negative_int, _positive_int


# ------------------------------------------------------------------------------ reconstruct
def add_reconstruct(sub) -> None:
    p = sub.add_parser("reconstruct", help="elevation map from a point-cloud file (.npy .ply .pcd .las .laz)",
                       description="Read a point cloud, move it into the sensor frame, project it into a map and fill "
                                   "it in with the model. Writes an .npz (height, mask, and uncertainty: each cell's standard "
                                   "deviation in metres, if the model predicts one) and a PNG preview.")
    p.add_argument("file", help="the point cloud (.npy (N,3), .ply, .pcd, .las, .laz)")
    p.add_argument("--out", default=None, metavar="OUT.npz", help="output (default: FILE with .npz); a PNG preview is written beside it")
    p.add_argument("--map-size", type=_positive_int, default=None, metavar="S",
                   help="cells per side (default: the model's training maps, 121 for the shipped model)")
    p.add_argument("--map-cell", type=float, default=None, metavar="M",
                   help="cell size in metres (default: the model's training maps, 0.25 for the shipped model)")
    p.add_argument("--transform", default=None, metavar="VALUES",
                   help="points -> sensor frame: 16 comma-separated values (a 4x4 matrix, row-major) or 6 (x,y,z,roll,pitch,yaw in m and degrees)")
    _add_model(p)
    _add_tta(p)
    _add_device(p)
    p.set_defaults(func=cmd_reconstruct)


def cmd_reconstruct(args) -> int:
    from pathlib import Path

    from ..core.geometry import MapGeometry
    from ..inference.maps import write_map
    from ..inference.pointclouds import apply_transform, read_point_cloud, transform_matrix
    from ..inference.reconstructor import Reconstructor
    from ..plots.maps import save_map_preview

    source = Path(args.file)
    if not source.is_file():  # before --out, which defaults to a name beside it
        raise ValueError(f"{str(source)!r}: no such file")
    out = Path(args.out) if args.out else source.with_suffix(".npz")
    if out.suffix != ".npz":
        raise ValueError(f"--out {str(out)!r}: must end in .npz")
    if not out.resolve().parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder {str(out.resolve().parent)!r} does not exist")
    matrix = transform_matrix([float(v) for v in args.transform.split(",")]) if args.transform else None
    points = read_point_cloud(source)
    if matrix is not None:
        points = apply_transform(points, matrix)
    rec = Reconstructor.load(args.model, device=args.device, tta=args.tta)
    geometry = MapGeometry(*rec.resolve_geometry(args.map_size, args.map_cell))
    maps = rec.reconstruct_all(points, geometry.size, geometry.cell)
    write_map(out, maps, geometry)
    png = out.with_suffix(".png")
    save_map_preview(maps["height"], maps["mask"], geometry.cell, png, title=source.name)
    print(json.dumps({"npz": str(out), "png": str(png), "points": int(len(points)), "observed_cells": int(maps["mask"].sum()),
                      "map_size": geometry.size, "map_cell": geometry.cell, "uncertainty": "uncertainty" in maps}))
    return 0


# ------------------------------------------------------------------------------ export-onnx
def add_export_onnx(sub) -> None:
    p = sub.add_parser("export-onnx", help="export the generator to ONNX, checked against torch with ONNX Runtime",
                       description="Export the generator (input 'condition' (B,C,S,S), output 'height' (B,1,S,S), and "
                                   "'log_variance' (B,1,S,S) if the model predicts its uncertainty) and "
                                   "check it against torch on generated scans; prints the largest difference and the "
                                   "latency of both.")
    p.add_argument("out", help="OUT.onnx")
    p.add_argument("--map-size", type=_positive_int, default=None, metavar="S",
                   help="cells per side, fixed in the graph (default: the model's training maps, 121 for the shipped model)")
    _add_model(p)
    p.set_defaults(func=cmd_export_onnx)


def cmd_export_onnx(args) -> int:
    from ..inference.onnx import check_onnx, export_onnx
    from ..inference.reconstructor import Reconstructor
    from ..sim import generate_batch

    rec = Reconstructor.load(args.model, device="cpu")
    map_size = rec.resolve_geometry(args.map_size, None)[0]
    path = export_onnx(rec.generator, args.out, rec.model_config.in_channels, map_size, uncertainty=rec.has_uncertainty)
    batch = generate_batch(4, {"data": {"map_size": map_size}}, seed=0, device="cpu")
    report = check_onnx(rec.generator, path, rec.condition(batch.scan, batch.mask), uncertainty=rec.has_uncertainty)
    report["onnx"] = str(path)
    print(json.dumps(report))
    if report["max_abs_diff"] > 1e-4:
        print(f"error: ONNX differs from torch by {report['max_abs_diff']:.2e} m (> 1e-4)", file=sys.stderr)
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
    _add_device(p)
    p.set_defaults(func=cmd_package_model)


def cmd_package_model(args) -> int:
    from pathlib import Path

    from ..evaluation.calibrate import package_model

    out = Path(args.out)
    if not out.resolve().parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder does not exist")
    print(json.dumps(package_model(args.checkpoint, out, calibrate=args.calibrate, device=args.device)))
    return 0
