""":func:`format_table`: a readable table of :func:`~.registry.run_benchmarks`' result, one
row helper per workload; "ours = N x anchor" compares our throughput with the anchor's on the
same workload (> 1: ours is faster)."""

from __future__ import annotations

Row = tuple[str, str, str, str]  # workload, parameters, median, throughput

FOOTER = [
    "median of repeats after one warm-up call (compilation excluded); device synchronised before each clock read",
    "ours = N x anchor: our throughput over the anchor's on the same work (> 1: ours is faster)",
]


# ------------------------------------------------------------------------------- numbers
def _rate(x: float) -> str:
    for scale, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if x >= scale:
            return f"{x / scale:.2f}{unit} "
    return f"{x:.2f} "


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.2f} ms" if seconds < 10 else f"{seconds:.2f} s"


def _x(ratio: float) -> str:
    return f"{ratio:.2f}x" if ratio < 10 else f"{ratio:.1f}x"


# ------------------------------------------------------------------------------- shared rows
def _missing_row(name: str, anchor: dict) -> Row:
    """An anchor (or runtime) that could not run, with its reason."""
    return (name, anchor.get("reason", "not available"), "", "")


def _processes_row(name: str, procs: dict, what: str, unit: str, single_per_s: float) -> Row:
    """The table row of a workload split over processes (``sim/parallel.py``)."""
    per_s = procs[f"{unit}_per_s"]
    n = procs["processes"]
    return (f"{name} {n} proc", f"{what} over {n} processes (sim/parallel.py); equal to 1 process: {'yes' if procs['equal_to_one_process'] else 'NO'}",
            _ms(procs["median_s"]), f"{_rate(per_s)}{unit}/s ({per_s / single_per_s:.2f}x 1 process)")


def _processes_over(procs: dict | None, anchor_timing: dict) -> str:
    """``", N proc = R"``: the process split's ratio to an anchor timing, when there is one."""
    if not procs or "processes_over_anchor" not in anchor_timing:
        return ""
    return f", {procs['processes']} proc = {_x(anchor_timing['processes_over_anchor'])}"


def _variant_row(label: str, c: dict) -> Row:
    """A TRAIN variant under its batch's row: ms/step, images/s and its ratio to plain."""
    return ("", label, _ms(c["median_s"]) + "/step", f"{c['images_per_s']:.2f} images/s ({_x(c['over_plain'])} plain)")


# ------------------------------------------------------------------------------- workloads
def _noise_rows(r: dict) -> list[Row]:
    p = r["params"]
    rows = [("noise", f"{p['batch']} fBm heightfields {p['size']}x{p['size']}, {p['octaves']} octaves",
             _ms(r["median_s"]), f"{_rate(r['samples_per_s'])}samples/s ({r['heightfields_per_s']:.0f} fields/s)")]
    procs = r.get("processes")
    if procs:
        rows.append(_processes_row("noise", procs, "the same fields, samples split", "samples", r["samples_per_s"]))
    a = r.get("anchor")
    if a and a["available"]:
        rows.append(("  anchor", f"pyfastnoiselite {a['version']} Perlin FBm, {a['octaves']} octaves, 1 thread, {a['samples']:,} samples",
                     _ms(a["median_s"]), f"{_rate(a['samples_per_s'])}samples/s; ours = {_x(a['ours_over_anchor'])} anchor{_processes_over(procs, a)}"))
    elif a:
        rows.append(_missing_row("  anchor", a))
    return rows


def _rays_anchor_rows(a: dict, procs: dict | None) -> list[Row]:
    """Open3D's timings (cast only and fresh, per thread count) and the agreement row."""
    rows = []
    for run in a["runs"]:
        threads = f"{a['cpu_count']} threads" if run["threads"] == "all" else "1 thread"
        for kind, what in (("cast", "cast only (BVH built)"), ("fresh", "fresh: BVH build + cast")):
            t = run[kind]
            rows.append(("  anchor", f"open3d {a['version']} RaycastingScene, {what}, {threads}",
                         _ms(t["median_s"]), f"{_rate(t['rays_per_s'])}rays/s; ours = {_x(t['ours_over_anchor'])} anchor{_processes_over(procs, t)}"))
    g = a["agreement"]
    rows.append(("  agreement", f"|t_ours - t_open3d| <= {1e3 * g['tolerance_m']:g} mm on {g['both_hit_within_tolerance']:,}"
                                f" of {g['both_hit']:,} rays both hit; one-sided hits {g['only_ours_hit']} ours, {g['only_anchor_hit']} open3d",
                 "", f"max |dt| {1e3 * g['max_abs_diff_m']:.3f} mm: {'AGREE' if g['agree'] else 'DISAGREE'}"))
    return rows


def _rays_rows(r: dict) -> list[Row]:
    p = r["params"]
    threads = p.get("threads", 1)
    rows = [("rays", f"{p['rays']:,} rays ({p['lidar']} {p['channels']}x{p['columns']}), {p['size']}x{p['size']} @ {p['cell_m']:g} m,"
                     f" cast_scans, {threads} thread{'s' if threads > 1 else ''}",
             _ms(r["median_s"]), f"{_rate(r['rays_per_s'])}rays/s (hits {100 * r['hit_fraction']:.1f}%)")]
    one = r.get("one_thread")
    if one:
        rows.append(("rays 1 thr", f"the same scan as one launch; equal to {threads} threads: {'yes' if one['equal_to_threads'] else 'NO'}",
                     _ms(one["median_s"]), f"{_rate(one['rays_per_s'])}rays/s ({r['rays_per_s'] / one['rays_per_s']:.2f}x faster with {threads})"))
    procs = r.get("processes")
    if procs:  # against one process on one thread
        rows.append(_processes_row("rays", procs, "the same scan, columns interleaved", "rays", (one or r)["rays_per_s"]))
    a = r.get("anchor")
    if a and a["available"]:
        rows.extend(_rays_anchor_rows(a, procs))
    elif a:
        rows.append(_missing_row("  anchor", a))
    return rows


def _stream_rows(r: dict) -> list[Row]:
    p = r["params"]
    stages = ("terrain", "ray_cast", "projection_truth")
    rows = []
    for run in r["runs"]:
        rows.append((f"stream B={run['batch']}",
                     f"generate_batch: {p['lidar']} {p['rays_per_scan']:,} rays, terrain {p['terrain_size']}^2, maps {p['map_size']}^2",
                     _ms(run["median_s"]), f"{_rate(run['pairs_per_s'])}pairs/s"))
        b, f = run["breakdown_s"], run["breakdown_fraction"]
        rows.append(("", "  terrain / ray cast / projection+truth",
                     " / ".join(_ms(b[k]) for k in stages), " / ".join(f"{100 * f[k]:.0f}%" for k in stages)))
    return rows


def _loader_rows(r: dict) -> list[Row]:
    p = r["params"]
    return [(f"loader w={run['workers']}", f"training stream, {p['lidar']}, batch {p['batch']}, {run['workers']} worker processes",
             _ms(run["seconds"] / run["batches"]), f"{_rate(run['pairs_per_s'])}pairs/s") for run in r["runs"]]


def _compile_row(c: dict) -> Row:
    if c["available"]:
        return _variant_row(f"  torch.compile (compile {c['compile_s']:.0f} s, excluded)", c)
    return ("", f"  torch.compile: {c['reason']}", "", "")


def _train_run_rows(run: dict, p: dict) -> list[Row]:
    """One batch size: plain, then the variants it has."""
    rows = [(f"train B={run['batch']}", f"{p['model']} model (ngf {p['ngf']}, ndf {p['ndf']}), steps on a fixed batch, {run['threads']} torch thread(s)",
             _ms(run["plain"]["median_s"]) + "/step", f"{run['plain']['images_per_s']:.2f} images/s")]
    if "plain_all_threads" in run:
        c = run["plain_all_threads"]
        rows.append(_variant_row(f"  the same with {c['threads']} torch threads", c))
    rows.append(_variant_row("  channels_last", run["channels_last"]))
    if "compile" in run:
        rows.append(_compile_row(run["compile"]))
    st = run["stream"]
    rows.append(("", f"  + training stream ({st['workers']} workers): data wait {100 * st['data_wait_share']:.0f}% of step time",
                 _ms(st["seconds"] / st["steps"]) + "/step", f"{st['images_per_s']:.2f} images/s ({_x(st['over_plain'])} plain)"))
    return rows


def _train_rows(r: dict) -> list[Row]:
    return [row for run in r["runs"] for row in _train_run_rows(run, r["params"])]


def _infer_batch_rows(r: dict, run: dict, batch: str, e: dict) -> list[Row]:
    """One batch size at one thread count: end to end, then the network under each runtime."""
    p = r["params"]
    what = f"reconstruct(points): {p['points_in_cloud']:,} points" if batch == "1" else f"project {batch} scans + predict_maps"
    rows = [(f"infer B={batch}", f"{what} -> {p['map_size']}^2 map ({p['model']} ngf {p['ngf']}"
                                 f"{', residual' if p['residual'] else ''}{', 8-orientation TTA' if p.get('tta') else ''}), "
                                 f"{run['threads']} thread(s)",
             _ms(e["median_s"]), f"{e['maps_per_s']:.1f} maps/s")]
    n = run["network"][batch]
    rows.append(("", "  network: torch", _ms(n["torch"]["median_s"]), ""))
    if "onnxruntime" in n:
        o = n["onnxruntime"]
        rows.append(("", f"  network: onnxruntime {r['onnxruntime']['version']} (max |diff| {n['max_abs_diff_m']:.1e} m)",
                     _ms(o["median_s"]), f"{_x(o['speedup_over_torch'])} torch"))
    return rows


def _single_map_rows(run: dict) -> list[Row]:
    """One map without the orientation average, with the shipped self-check and without it."""
    rows = []
    for e in run["single_map"].values():
        what = ("self-check" + (" + reach" if e["reach"] else "")) if e["checks"] else "no self-check"
        rows.append(("infer 1 map" if not rows else "", f"reconstruct(points), no TTA, {what}, {run['threads']} thread(s)", _ms(e["median_s"]), ""))
    return rows


def _infer_rows(r: dict) -> list[Row]:
    rows = [row for run in r["runs"] for batch, e in run["end_to_end"].items() for row in _infer_batch_rows(r, run, batch, e)]
    rows += [row for run in r["runs"] if "single_map" in run for row in _single_map_rows(run)]
    if not r["onnxruntime"]["available"]:
        rows.append(_missing_row("  onnxruntime", r["onnxruntime"]))
    return rows


WORKLOAD_ROWS = {"noise": _noise_rows, "rays": _rays_rows, "stream": _stream_rows, "loader": _loader_rows,
                 "train": _train_rows, "infer": _infer_rows}  # in the table's order


# ------------------------------------------------------------------------------- layout
def _header(report: dict) -> str:
    env = report["environment"]
    return (f"warp-terrain {env['warp_terrain']} bench on {env['device']} ({env['device_name']}, {env['cpu_count']} CPUs)"
            f"  warp {env['warp']}  torch {env['torch']}{'  [quick]' if report.get('quick') else ''}")


def _layout(rows: list[Row]) -> list[str]:
    """Rows in columns as wide as their widest cell (the last left ragged); a rule under the first."""
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    lines = []
    for k, row in enumerate(rows):
        lines.append("  ".join(cell.ljust(w) if i < 3 else cell for i, (cell, w) in enumerate(zip(row, widths))).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return lines


def format_table(report: dict) -> str:
    """A readable table of :func:`~.registry.run_benchmarks`' result; "ours = N x anchor" compares
    our throughput with the anchor's on the same workload (> 1: ours is faster)."""
    rows: list[Row] = [("workload", "parameters", "median", "throughput")]
    res = report["results"]
    for name, workload_rows in WORKLOAD_ROWS.items():
        if name in res:
            rows.extend(workload_rows(res[name]))
    return "\n".join([_header(report), "", *_layout(rows), "", *FOOTER])
