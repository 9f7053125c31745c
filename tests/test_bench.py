"""``warp-terrain bench``: the TRAIN and INFER workloads, the anchors (pyfastnoiselite, Open3D)
and the 1 mm agreement of our ray caster with Open3D's ``RaycastingScene``."""

import json
import sys

import numpy as np
import pytest

from warp_terrain.bench import bench_noise, bench_rays, compare_hits, format_table, heightfield_triangles, open3d_hits
from warp_terrain.cli import main
from warp_terrain.sim import ObstacleConfig, TerrainConfig, lidar_preset
from warp_terrain.sim.scan import trace
from warp_terrain.sim.terrain import make_heightfields


def test_bench_quick_train_and_infer(capsys):
    assert main(["bench", "--json", "--quick", "--only", "train,infer", "--device", "cpu"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["results"]) == {"train", "infer"}
    train = report["results"]["train"]
    assert train["params"]["model"] == "paper"
    (run,) = train["runs"]
    for variant in ("plain", "channels_last", "stream"):
        assert run[variant]["images_per_s"] > 0
    assert 0.0 < run["stream"]["data_wait_share"] < 1.0
    assert run["compile"] == {"available": False, "reason": "skipped (--quick)"}
    infer = report["results"]["infer"]
    assert infer["params"]["points_in_cloud"] > 1000
    for r in infer["runs"]:
        assert set(r["end_to_end"]) == {"1", "4"}
        assert all(e["median_ms"] > 0 for e in r["end_to_end"].values())
        single = r["single_map"]
        assert (single["self_check"]["checks"], single["self_check"]["reach"], single["no_check"]["checks"]) == (True, True, False)
        assert single["self_check"]["median_ms"] > 0 and single["no_check"]["median_ms"] > 0
        if infer["onnxruntime"]["available"]:
            for n in r["network"].values():
                assert n["max_abs_diff_m"] < 1e-3 and n["onnxruntime"]["median_ms"] > 0
    table = format_table(report)
    assert "images/s" in table and "data wait" in table and "reconstruct(points)" in table
    assert "no TTA, self-check + reach, 1 thread(s)" in table and "no TTA, no self-check, 1 thread(s)" in table


def test_rays_times_the_public_cast_scans_on_its_threads_and_one(monkeypatch):
    """RAYS' figure is ``cast_scans`` with its default CPU threads (two cores here), beside the
    same scan as one launch; both give the same points."""
    from warp_terrain.sim import threads

    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    r = bench_rays("cpu", quick=True, anchor=False)
    assert r["params"]["api"] == "cast_scans" and r["params"]["threads"] == 2
    one = r["one_thread"]
    assert one["equal_to_threads"] is True and one["rays_per_s"] > 0
    assert one["rays_per_s"] == pytest.approx(r["params"]["rays"] / one["median_s"])
    table = format_table({"environment": _env(), "results": {"rays": r}})
    assert "cast_scans, 2 threads" in table and "equal to 2 threads: yes" in table


def test_noise_anchor_runs_the_same_samples():
    pytest.importorskip("pyfastnoiselite")
    r = bench_noise("cpu", quick=True)
    a = r["anchor"]
    p = r["params"]
    assert a["available"] and a["samples"] == p["batch"] * p["size"] ** 2
    assert a["octaves"] == p["octaves"] and a["frequency_per_m"] == pytest.approx(1.0 / p["feature_size_m"])
    assert a["samples_per_s"] > 0 and a["ours_over_anchor"] == pytest.approx(r["samples_per_s"] / a["samples_per_s"])
    lo, hi = a["value_range"]
    assert -1.0 <= lo < hi <= 1.0  # real fBm values, not a constant
    assert "pyfastnoiselite" in format_table({"environment": _env(), "results": {"noise": r}})


def test_missing_anchor_is_reported_not_raised(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyfastnoiselite", None)  # import fails as if not installed
    monkeypatch.setitem(sys.modules, "pyfastnoiselite.pyfastnoiselite", None)
    r = bench_noise("cpu", quick=True)
    assert r["anchor"]["available"] is False and "pyfastnoiselite" in r["anchor"]["reason"]
    assert r["samples_per_s"] > 0
    assert "not importable" in format_table({"environment": _env(), "results": {"noise": r}})


def test_rays_anchor_agrees_to_a_millimetre():
    pytest.importorskip("open3d")
    r = bench_rays("cpu", quick=True)
    a = r["anchor"]
    assert a["available"] and a["version"] != "unknown" and [run["threads"] for run in a["runs"]] == ["all", "1"]
    for run in a["runs"]:
        assert run["cast"]["rays_per_s"] > 0 and run["fresh"]["median_s"] >= 0
    g = a["agreement"]
    assert g["agree"] and g["both_hit"] > 0.2 * g["rays"] and g["max_abs_diff_m"] <= 1e-3
    assert "AGREE" in format_table({"environment": _env(), "results": {"rays": r}})


def test_open3d_and_our_caster_hit_the_same_triangles():
    """A tiny heightfield with boxes, rocks and pits: every ray both hit agrees to 1 mm, and
    (almost) no ray hits in one caster only. A ray grazing a box's top edge within a few
    micrometres can go either way in float32 (1 ray in ~470,000 did on obstacle terrains)."""
    pytest.importorskip("open3d")
    cfg = TerrainConfig(octaves=4, amplitude=1.0, feature_size=6.0, cell=0.1, keep_out=1.5)
    cfg.boxes = ObstacleConfig(count_min=2, count_max=3)
    cfg.rocks = ObstacleConfig(count_min=1, count_max=2)
    cfg.pits = ObstacleConfig(count_min=1, count_max=2)
    cfg.validate()
    lidar = lidar_preset("hdl32e", azimuth_step_deg=2.0, range_noise_std=0.0, dropout=0.0)
    heights = make_heightfields(2, 161, cfg, seed=7, device="cpu", obstacle_region=6.0)
    points, sensor_z = trace(heights, cfg.cell, lidar, 0, "cpu", reach=0.0)
    h, z, p = heights.numpy(), sensor_z.numpy(), points.numpy()
    for b in range(h.shape[0]):
        ours = np.linalg.norm(p[b].astype(np.float64), axis=1)
        theirs = open3d_hits(h[b], cfg.cell, lidar, float(z[b]), nthreads=1)
        g = compare_hits(ours, theirs)
        assert g["both_hit"] > 0.25 * g["rays"]
        assert g["both_hit_within_tolerance"] == g["both_hit"], g
        assert g["only_ours_hit"] + g["only_anchor_hit"] <= 1e-3 * g["rays"], g


def test_heightfield_triangles_follow_the_casters_diagonal():
    h = np.arange(6, dtype=np.float32).reshape(2, 3)
    vertices, triangles = heightfield_triangles(h, 0.5)
    assert vertices.shape == (6, 3) and triangles.shape == (4, 3) and triangles.dtype == np.uint32
    np.testing.assert_allclose(vertices[0], [-0.25, -0.5, 0.0])
    np.testing.assert_allclose(vertices[5], [0.25, 0.5, 5.0])
    # cell (0, 0): (i,j)-(i+1,j)-(i+1,j+1) and (i,j)-(i+1,j+1)-(i,j+1), vertex index i * W + j
    assert triangles[0].tolist() == [0, 3, 4] and triangles[2].tolist() == [0, 4, 1]
    # counter-clockwise from above: every normal points up
    v = vertices[triangles]
    assert (np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2] > 0).all()


def _env() -> dict:
    from warp_terrain.bench import environment

    return environment("cpu")
