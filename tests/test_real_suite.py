"""The real-data suite: its scan families (cells hidden, raised cells), its DEM families, and
what it says when the data are missing. Every input is made here: nothing needs ``make real-data``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from warp_terrain.evaluation import BASELINES
from warp_terrain.evaluation.real import (
    DEM_FAMILIES,
    HIDE_SHARE,
    MISSING_HINT,
    RAISED_M,
    REAL_SEED_BASE,
    SCAN_FAMILIES,
    evaluate_real,
    raised_cells,
    real_markdown,
    scan_family_set,
)

rasterio = pytest.importorskip("rasterio")


def flat_scan_with_a_box(path, z0=-1.8, box=(1.875, 2.875, -1.125, -0.125), top=-0.8):
    """A dense synthetic cloud: the plane z = z0 over +-15 m, and a box top at ``top`` over x in
    [box[0], box[1]), y in [box[2], box[3]): 4 x 4 whole map cells of 0.25 m that rise 1 m."""
    g = np.arange(-15.0, 15.0, 0.05)
    x, y = np.meshgrid(g, g, indexing="ij")
    z = np.full_like(x, z0)
    inside = (x >= box[0]) & (x < box[1]) & (y >= box[2]) & (y < box[3])
    z[inside] = top
    np.savez(path, points=np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1).astype(np.float32))


def test_raised_cells_are_exactly_what_stands_above_the_local_ground():
    h = np.full((41, 41), -1.8)
    observed = np.ones_like(h, bool)
    h[10:13, 20:23] = -1.8 + RAISED_M + 0.5  # a box of 3 x 3 cells
    h[30, 30] = -1.8 + RAISED_M - 0.05  # a bump below the threshold
    observed[0:5, 0:5] = False
    raised = raised_cells(h, observed)
    expected = np.zeros_like(observed)
    expected[10:13, 20:23] = True
    np.testing.assert_array_equal(raised, expected)


def test_scan_families_hide_a_share_of_the_observed_cells(tmp_path):
    family = SCAN_FAMILIES[2]
    for name in family.files:
        flat_scan_with_a_box(tmp_path / name)
    ss = scan_family_set(family, tmp_path, repeats=3, map_size=61, map_cell=0.25, seed=5)
    assert ss.scan.shape == (6, 1, 61, 61)  # 2 scans x 3 repeats
    observed = ss.mask.bool() | ss.hidden
    assert bool(observed.all())  # the cloud covers the whole map
    counts = ss.hidden.flatten(1).sum(dim=1)
    assert torch.equal(counts, torch.full((6,), round(HIDE_SHARE * 61 * 61)))
    assert not bool((ss.mask.bool() & ss.hidden).any())  # hidden cells are not shown
    assert torch.equal(ss.scan[ss.hidden], torch.zeros(int(counts.sum())))  # ... and read as the fill value
    assert not torch.equal(ss.hidden[0], ss.hidden[1])  # repeats hide other cells
    torch.testing.assert_close(ss.measured[ss.mask.bool()], ss.scan[ss.mask.bool()])
    # the box's 16 cells are raised, the plane's are not
    box = ss.measured.round(decimals=3) == -0.8
    assert int(box[0].sum()) == 16
    assert torch.equal(ss.raised, ss.hidden & box)
    again = scan_family_set(family, tmp_path, repeats=3, map_size=61, map_cell=0.25, seed=5)
    assert torch.equal(again.hidden, ss.hidden)


def test_the_suite_scores_hidden_cells_and_names_what_is_missing(tmp_path):
    family = SCAN_FAMILIES[1]
    for name in family.files:
        flat_scan_with_a_box(tmp_path / name)

    def oracle(scan, mask):  # what the full scan measured: a perfect fill
        return oracle.measured

    predictors = {"model": oracle, "nearest": BASELINES["nearest"], "linear": BASELINES["linear"]}
    ss = scan_family_set(family, tmp_path, 1, 121, 0.25, 0)
    oracle.measured = ss.measured
    results = evaluate_real(predictors, data_dir=tmp_path, repeats=1, device="cpu", synthetic=False)
    assert [m["family"] for m in results["missing"]] == [f.name for f in DEM_FAMILIES + SCAN_FAMILIES if f is not family]
    assert all(m["hint"] == MISSING_HINT for m in results["missing"])
    (entry,) = results["families"]
    assert entry["metrics"]["model"]["rmse_hidden"] == 0.0
    # on the plane a linear fill is exact; only the box's edges cost anything
    assert entry["metrics"]["linear"]["rmse_hidden_ground"] < 0.02
    text = real_markdown(results)
    assert family.name in text and "missing:" in text and "make real-data" in text


def test_a_dem_family_is_real_ground_scanned(tmp_path):
    """A tilted plane as 'mammoth_dem.tif': the family's targets are that plane (slope 0.1)."""
    from affine import Affine

    n, cell = 400, 1.0
    x = np.arange(n) * cell
    z = (0.1 * x[None, :] + 0.0 * x[:, None]).astype(np.float32) + 100.0
    path = tmp_path / DEM_FAMILIES[0].files[0]
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:26911",
                       transform=Affine(cell, 0, 500000.0, 0, -cell, 4100000.0)) as dst:
        dst.write(z, 1)

    def truth(scan, mask):
        return truth.target

    from warp_terrain.evaluation.real import dem_family_set

    ts = dem_family_set(DEM_FAMILIES[0], tmp_path, 2, "cpu")
    gy, gx = np.gradient(ts.target[0, 0].numpy(), 0.25)
    assert np.hypot(gx, gy)[5:-5, 5:-5] == pytest.approx(0.1, abs=1e-3)  # the plane's slope in any heading
    truth.target = ts.target
    results = evaluate_real({"model": truth}, data_dir=tmp_path, size=2, device="cpu", synthetic=False)
    (entry,) = [e for e in results["families"] if e["family"] == DEM_FAMILIES[0].name]
    assert entry["metrics"]["model"]["rmse_unobserved"] == 0.0


def test_map_statistics_of_a_tilted_plane_and_a_box():
    from warp_terrain.evaluation.coverage import map_statistics

    n, cell, deg = 41, 0.25, 12.0
    c = (np.arange(n) - 20) * cell
    x, y = np.meshgrid(c, c, indexing="ij")
    plane = np.tan(np.radians(deg)) * (0.6 * x + 0.8 * y)  # downhill direction (0.6, 0.8)
    target = torch.from_numpy(plane).float()[None, None]
    stats = map_statistics(target, torch.ones_like(target), cell)
    assert stats["slope_deg_median"] == pytest.approx(deg, abs=1e-3)
    assert stats["local_slope_deg_median"] == pytest.approx(deg, abs=1e-2)
    assert stats["relief_m_median"] == pytest.approx(np.tan(np.radians(deg)) * 1.4 * 40 * cell, rel=1e-5)
    box = target.clone()
    box[..., 10:14, 10:15] += 1.0  # 20 cells of obstacle
    assert map_statistics(box, torch.ones_like(box), cell, ground=target)["obstacle_share"] == pytest.approx(20 / n**2)


def test_evaluate_real_from_the_command_line(tmp_path, capsys):
    from warp_terrain.cli import main

    family = SCAN_FAMILIES[1]
    for name in family.files:
        flat_scan_with_a_box(tmp_path / name)
    assert main(["evaluate", "--real", "--real-data", str(tmp_path), "--baselines", "nearest,linear", "--repeats", "1",
                 "--size", "1", "--markdown", str(tmp_path / "real.md")]) == 0
    out = capsys.readouterr().out
    assert family.name in out and "missing:" in out and (tmp_path / "real.md").read_text() in out + "\n"
    assert main(["evaluate", "--real", "--robustness"]) == 2


def test_the_suite_reports_how_often_the_error_lies_within_sigma(tmp_path):
    """A predictor off by 0.1 m on every cell, claiming sigma 0.15 m on half the map and 0.08 m
    on the other: the hidden cells in the first half are within 1 sigma, the others within 2
    sigma only, so the shares are the halves' shares of the suite's hidden cells."""
    family = SCAN_FAMILIES[1]
    for name in family.files:
        flat_scan_with_a_box(tmp_path / name)
    ss = scan_family_set(family, tmp_path, 1, 121, 0.25, REAL_SEED_BASE + 100 + SCAN_FAMILIES.index(family))  # the suite's draw
    sigma = torch.full_like(ss.measured, 0.08)
    sigma[..., :60, :] = 0.15

    def offset(scan, mask):
        return ss.measured + 0.1, sigma

    results = evaluate_real({"model": offset, "nearest": BASELINES["nearest"]}, data_dir=tmp_path, repeats=1, device="cpu", synthetic=False)
    (entry,) = results["families"]
    m = entry["metrics"]["model"]
    first_half = float(ss.hidden[..., :60, :].sum() / ss.hidden.sum())
    assert m["within_1sigma"] == pytest.approx(first_half, abs=1e-6) and 0.2 < first_half < 0.8
    assert m["within_2sigma"] == 1.0 and "within_1sigma" not in entry["metrics"]["nearest"]
    assert f"| {family.name} | {100 * first_half:.0f} % | 100 % |" in real_markdown(results)
