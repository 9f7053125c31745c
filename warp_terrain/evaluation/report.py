"""Rendering ``evaluate``'s results: plain-text and Markdown tables, and strict JSON.

:func:`format_table` prints one table per setting (rows: methods, columns: the metrics any
method has) and the mean time per map; :func:`format_markdown` adds a summary of the RMSE on
unobserved cells (every setting x method, the best in bold) and how the numbers were made;
:func:`json_ready` replaces NaN/inf by None so ``json.dumps(..., allow_nan=False)`` accepts it.
"""

from __future__ import annotations

import math

__all__ = [
    "COLUMNS",
    "format_markdown",
    "format_table",
    "json_ready",
]

#: ``(metric key, column title)`` in table order; a column appears when any method has the metric.
COLUMNS = (
    ("rmse_unobserved", "RMSE unobs (m)"),
    ("mae_unobserved", "MAE unobs (m)"),
    ("rmse_observed", "RMSE obs (m)"),
    ("mae_observed", "MAE obs (m)"),
    ("rmse_in_range", "RMSE in-range (m)"),
    ("mae_in_range", "MAE in-range (m)"),
    ("obstacle_iou", "obstacle IoU"),
    ("pit_recall", "pit recall"),
    ("within_1sigma", "unobs within 1 sigma"),
    ("within_2sigma", "unobs within 2 sigma"),
    ("rms_sigma", "RMS sigma unobs (m)"),
    ("ms_per_map", "ms/map"),
)


def _fmt(key: str, value) -> str:
    """One table cell: ms with 1 decimal, shares with 3, metres with 4; ``n/a`` for None/NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if key == "ms_per_map":
        return f"{value:.1f}"
    return f"{value:.3f}" if key in ("obstacle_iou", "pit_recall", "within_1sigma", "within_2sigma") else f"{value:.4f}"


def _rows(entry: dict) -> tuple[list[str], list[list[str]]]:
    """``(header, rows)`` of one setting's table: one row per method."""
    methods = list(entry["metrics"])
    keys = [k for k, _ in COLUMNS if any(k in entry["metrics"][m] for m in methods)]
    head = ["method"] + [dict(COLUMNS)[k] for k in keys]
    body = [[m] + [_fmt(k, entry["metrics"][m].get(k)) for k in keys] for m in methods]
    return head, body


def _best(entry: dict) -> str:
    """The method with the lowest RMSE on unobserved cells (``n/a`` if none has one)."""
    scores = {m: v["rmse_unobserved"] for m, v in entry["metrics"].items() if not math.isnan(v["rmse_unobserved"])}
    return min(scores, key=scores.get) if scores else "n/a"


def _title(entry: dict) -> str:
    return (f"{entry['terrain']}, noise {100 * entry['noise']:g}%: {entry['samples']} samples, "
            f"{100 * entry['observed_share']:.1f}% of cells observed")


def format_table(results: dict) -> str:
    """Plain-text tables, one per setting (rows: methods), then the mean time per map."""
    lines = []
    for entry in results["settings"]:
        head, body = _rows(entry)
        widths = [max(len(r[i]) for r in [head] + body) for i in range(len(head))]
        lines.append(_title(entry))
        lines.append("  ".join(h.ljust(w) if i == 0 else h.rjust(w) for i, (h, w) in enumerate(zip(head, widths))))
        for r in body:
            lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        lines.append("")
    lines.append("mean time per map: " + ", ".join(f"{m} {ms:.1f} ms" for m, ms in results["ms_per_map"].items()))
    return "\n".join(lines)


def format_markdown(results: dict) -> str:
    """Markdown: a summary (RMSE on unobserved cells, every setting x method), one table per
    setting, the time per map, and how the numbers were made."""
    cfg = results["config"]
    methods = results["methods"]
    out = ["## Evaluation", ""]
    out.append(
        f"{cfg['size']} test samples per setting (seeds from {cfg['test_seed_base']}, never used by training or "
        f"validation), {cfg['lidar']} LIDAR, {cfg['map_size']} x {cfg['map_size']} maps of {cfg['map_cell_m']:g} m, "
        f"no augmentation. RMSE/MAE in metres on unobserved cells, observed cells and the in-range disc "
        f"(radius {cfg['in_range_radius_m']:g} m); obstacle IoU and pit recall against the bare ground at "
        f"{cfg['obstacle_threshold_m']:g} m; time per map on {cfg['device']}."
    )
    out += ["", "### RMSE on unobserved cells (m)", ""]
    out.append("| setting | " + " | ".join(methods) + " | best |")
    out.append("|---|" + "---:|" * len(methods) + "---|")
    for entry in results["settings"]:
        best = _best(entry)
        cells = []
        for m in methods:
            text = _fmt("rmse_unobserved", entry["metrics"][m]["rmse_unobserved"])
            cells.append(f"**{text}**" if m == best else text)
        out.append(f"| {entry['setting']} | " + " | ".join(cells) + f" | {best} |")
    for entry in results["settings"]:
        head, body = _rows(entry)
        out += ["", f"### {_title(entry)}", ""]
        out.append("| " + " | ".join(head) + " |")
        out.append("|---|" + "---:|" * (len(head) - 1))
        out += ["| " + " | ".join(r) + " |" for r in body]
    out += ["", "### Time per map (mean over all settings)", ""]
    out.append("| method | ms/map |")
    out.append("|---|---:|")
    out += [f"| {m} | {ms:.1f} |" for m, ms in results["ms_per_map"].items()]
    return "\n".join(out) + "\n"


def json_ready(obj):
    """``obj`` with NaN/inf floats replaced by None (strict JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    return obj
