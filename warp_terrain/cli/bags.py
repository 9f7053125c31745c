"""``warp-terrain reconstruct BAG``: one map per PointCloud2 message (or per Nth) of a ROS bag,
written as ``STEM_INDEX.npz`` + ``.png`` into a folder, with a progress bar on stderr."""

from __future__ import annotations

import json
import sys
from pathlib import Path

MAP_SUFFIXES = (".npz", ".tif", ".tiff")


def bag_output_folder(source: Path, out: str | None) -> Path:
    """The folder a bag's maps go to: ``--out`` (made if its parent exists) or ``STEM_maps``
    beside the bag; ValueError for a file name or a folder that cannot be made."""
    if out is None:
        return source.resolve().parent / f"{_stem(source)}_maps"
    folder = Path(out)
    if folder.suffix.lower() in MAP_SUFFIXES:
        raise ValueError(f"--out {out!r}: a bag gives one map per message: --out names a folder for them")
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"--out {out!r}: is a file, not a folder")
    if not folder.exists() and not folder.resolve().parent.is_dir():
        raise ValueError(f"--out {out!r}: the folder {str(folder.resolve().parent)!r} does not exist")
    return folder


def _stem(source: Path) -> str:
    return source.name if source.is_dir() else source.stem


def reconstruct_bag(args, sources: list[Path], matrix) -> int:
    """The bag branch of ``cmd_reconstruct``: every check (one bag, its topic, the folder, no
    file overwritten without --overwrite, options a bag cannot take) before the model loads."""
    import numpy as np
    from tqdm import tqdm

    from ..core.geometry import MapGeometry
    from ..inference.bags import BagClouds
    from ..inference.maps import write_map
    from ..inference.pointclouds import apply_transform
    from ..inference.reconstructor import Reconstructor
    from ..plots.maps import save_map_preview

    if len(sources) != 1:
        raise ValueError(f"a ROS bag is read on its own: give one bag per run, not {len(sources)} inputs")
    for option in ("usd", "crs"):
        if getattr(args, option, None) is not None:
            raise ValueError(f"--{option} is not supported for ROS bags yet (one .npz per message)")
    if getattr(args, "format", None) not in (None, "npz"):
        raise ValueError(f"--format {args.format}: a bag's maps are written as .npz")
    source = sources[0]
    clouds = BagClouds(source, topic=args.topic, every=args.every or 1)
    folder = bag_output_folder(source, args.out)
    width = max(4, len(str(clouds.count - 1)))
    name = _stem(source)
    planned = [folder / f"{name}_{index:0{width}d}{suffix}" for index in range(0, clouds.count, clouds.every) for suffix in (".npz", ".png")]
    if not getattr(args, "overwrite", False):
        for path in planned:
            if path.exists():
                raise ValueError(f"{str(path)!r}: exists; pass --overwrite to replace it")
    rec = Reconstructor.load(args.model, device=args.device, tta=args.tta, centre_cells=getattr(args, "centre_cells", None))
    geometry = MapGeometry(*rec.resolve_geometry(args.map_size, args.map_cell))
    folder.mkdir(exist_ok=True)  # every check passed: a refused run leaves no folder
    common = {"input": str(source), "topic": clouds.topic}
    with tqdm(total=len(clouds), desc=name, unit="map", file=sys.stderr, dynamic_ncols=True) as bar:
        for cloud in clouds:
            points = cloud.points if matrix is None else apply_transform(cloud.points, matrix)
            stamp = {"index": cloud.index, "timestamp": cloud.timestamp}
            inside = (np.abs(points[:, :2]) < geometry.half_extent).all(axis=1).any() if len(points) else False
            if not inside:  # a message with no return in the map: say so and go on with the stream
                why = "no points" if not len(points) else f"none of its {len(points)} points falls inside the map"
                bar.write(f"warning: {source.name}: message {cloud.index} on {clouds.topic}: {why}; skipped", file=sys.stderr)
                print(json.dumps({**common, **stamp, "skipped": why}), flush=True)
                bar.update()
                continue
            try:
                maps = rec.reconstruct_all(points, geometry.size, geometry.cell)
            except ValueError as err:
                raise ValueError(f"{str(source)!r}: message {cloud.index} on {clouds.topic}: {err}") from None
            npz = folder / f"{name}_{cloud.index:0{width}d}.npz"
            write_map(npz, maps, geometry)
            png = npz.with_suffix(".png")
            save_map_preview(maps["height"], maps["mask"], geometry.cell, png, title=f"{source.name} #{cloud.index}",
                             uncertainty=maps.get("uncertainty"))
            print(json.dumps({**common, **stamp, "map": str(npz), "format": "npz", "png": str(png), "points": int(len(points)),
                              "observed_cells": int(maps["mask"].sum()), "map_size": geometry.size, "map_cell": geometry.cell,
                              "uncertainty": "uncertainty" in maps}), flush=True)
            bar.update()
    return 0
