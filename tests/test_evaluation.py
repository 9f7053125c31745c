"""Evaluation: metrics with known answers, each classical fill on a tiny known case, the test
sets' seeds, the obstacle-free twin, a wrapped model and the ``evaluate`` command."""

import json
import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from warp_terrain.cli import main
from warp_terrain.data.seeds import VALIDATION_SEED_BASE, batch_seed, validation_seed
from warp_terrain.evaluation import (
    BASELINES,
    TEST_SEED_BASE,
    bare_config,
    error_metrics,
    eval_seeds,
    json_ready,
    make_eval_set,
    masked_mae,
    masked_rmse,
    nearest_fill,
    obstacle_iou,
    pit_recall,
    range_cells,
    setting_config,
)
from warp_terrain.inference.predictor import load_predictor, model_predictor
from warp_terrain.sim import generate_batch
from warp_terrain.sim.batch import terrain_size


def t(a) -> torch.Tensor:
    """A (1, 1, H, W) float32 tensor from a 2-D array."""
    return torch.as_tensor(np.asarray(a, dtype=np.float32))[None, None]


def disc(size: int, radius: float) -> np.ndarray:
    c = np.arange(size) - (size - 1) / 2
    return c[:, None] ** 2 + c[None, :] ** 2 <= radius**2


# ------------------------------------------------------------------------------ metrics
def test_constant_error_on_unobserved_cells():
    target = np.linspace(-2, 1, 11 * 11).reshape(11, 11)
    mask = np.zeros((11, 11))
    mask[::2, ::2] = 1
    pred = np.where(mask > 0, target, target + 0.1)
    m = error_metrics(t(pred), t(target), t(mask))
    assert m["rmse_unobserved"] == pytest.approx(0.1, abs=1e-6)
    assert m["mae_unobserved"] == pytest.approx(0.1, abs=1e-6)
    assert m["rmse_observed"] == pytest.approx(0.0, abs=1e-7)
    assert m["mae_observed"] == pytest.approx(0.0, abs=1e-7)
    share = 1 - mask.mean()  # every cell: 0.1 on the unobserved share, 0 elsewhere
    assert m["rmse_in_range"] == pytest.approx(0.1 * math.sqrt(share), abs=1e-6)
    assert m["mae_in_range"] == pytest.approx(0.1 * share, abs=1e-6)


def test_rmse_and_mae_pool_cells_and_are_nan_without_cells():
    pred, target = t([[0.3, -0.4, 5.0]]), t([[0.0, 0.0, 5.0]])
    cells = t([[1, 1, 0]]).bool()
    assert masked_rmse(pred, target, cells) == pytest.approx(math.sqrt((0.09 + 0.16) / 2), abs=1e-6)
    assert masked_mae(pred, target, cells) == pytest.approx(0.35, abs=1e-6)
    none = torch.zeros_like(cells)
    assert math.isnan(masked_rmse(pred, target, none)) and math.isnan(masked_mae(pred, target, none))
    with pytest.raises(ValueError, match="must match"):
        masked_rmse(pred, target[..., :2], cells)


def test_range_cells_disc():
    # 5 x 5 cells of 1 m: radius min(inf, 2.5) leaves out only the four corners (2^2 + 2^2 > 2.5^2)
    cells = range_cells(5, 1.0)
    assert cells.shape == (1, 1, 5, 5) and int(cells.sum()) == 21
    assert not cells[0, 0, 0, 0] and cells[0, 0, 0, 2]
    assert int(range_cells(5, 1.0, max_range=1.0).sum()) == 5  # the centre and its 4 neighbours
    big = range_cells(121, 0.25, max_range=100.0)
    assert torch.equal(big[0, 0], torch.from_numpy(disc(121, 60.5)))
    with pytest.raises(ValueError, match="map_cell"):
        range_cells(5, 0.0)


def test_obstacle_iou_of_discs_and_squares():
    ground = np.add.outer(np.linspace(-1, 1, 15), np.linspace(0, 0.5, 15))  # sloped bare ground
    target = ground + 1.0 * disc(15, 3)  # 29 cells: Gauss's circle count N(3)
    pred = ground + 1.0 * disc(15, 2)  # 13 cells, all inside: N(2)
    assert obstacle_iou(t(pred), t(target), t(ground)) == pytest.approx(13 / 29)
    assert obstacle_iou(t(target), t(target), t(ground)) == 1.0
    # a prediction 0.29 m above ground is not an obstacle at the 0.3 m threshold
    assert obstacle_iou(t(ground + 0.29), t(target), t(ground)) == 0.0
    # two 4 x 4 squares overlapping by 4 x 2: 8 / 24
    a, b = np.zeros((10, 10)), np.zeros((10, 10))
    a[2:6, 2:6], b[2:6, 4:8] = 2.0, 2.0
    assert obstacle_iou(t(b), t(a), t(np.zeros((10, 10)))) == pytest.approx(1 / 3)
    assert math.isnan(obstacle_iou(t(ground), t(ground), t(ground)))


def test_pit_recall():
    ground = np.full((6, 6), -1.8)
    target = ground.copy()
    target[1, :5] -= 1.0  # 5 pit cells, 1 m deep
    target[3, 0] -= 0.2  # a dip, not a pit at 0.3 m
    pred = ground.copy()
    pred[1, :2] -= 0.2  # found: more than 0.15 m below the ground
    pred[1, 2:4] -= 0.1  # not deep enough
    assert pit_recall(t(pred), t(target), t(ground)) == pytest.approx(2 / 5)
    assert pit_recall(t(target), t(target), t(ground)) == 1.0
    assert math.isnan(pit_recall(t(ground), t(ground), t(ground)))


# ------------------------------------------------------------------------------ baselines
def plane(shape, a=0.1, b=-0.05, c=-1.5):
    i, j = np.indices(shape)
    return a * i + b * j + c


def test_linear_and_plane_fits_reconstruct_a_sparse_plane(rng):
    z = plane((21, 21))
    known = rng.random((21, 21)) < 0.2
    known[[0, 0, -1, -1], [0, -1, 0, -1]] = True  # the corners: the hull is the whole map
    scan, mask = t(np.where(known, z, 0.0)), t(known)
    for name in ("linear", "plane"):
        out = BASELINES[name](scan, mask)
        np.testing.assert_allclose(out[0, 0].numpy(), z, atol=1e-5, err_msg=name)


def test_linear_falls_back_to_nearest_outside_the_hull_and_on_a_line():
    z = plane((9, 9))
    known = np.zeros((9, 9), bool)
    known[4, 2:7] = True  # collinear: no triangle
    out = BASELINES["linear"](t(np.where(known, z, 0)), t(known))
    np.testing.assert_allclose(out.numpy(), nearest_fill(t(np.where(known, z, 0)), t(known)).numpy())


def test_nearest_reproduces_a_checkerboard_from_tile_centres():
    # 5 x 5 tiles alternating 0 / 1 m; only each tile's centre is observed. Every cell is at most
    # 2.83 cells from its own tile's centre and at least 3 from any other: nearest is exact.
    board = (np.add.outer(np.arange(20) // 5, np.arange(20) // 5) % 2).astype(float)
    known = np.zeros((20, 20), bool)
    known[2::5, 2::5] = True
    out = nearest_fill(t(np.where(known, board, 0)), t(known))
    np.testing.assert_array_equal(out[0, 0].numpy(), board)


@pytest.mark.parametrize("name", ["biharmonic", "harmonic", "telea", "ns"])
def test_inpainting_keeps_observed_cells_and_fills_a_constant(name, rng):
    """Observed cells exactly, a constant map and the map's border; what is specific to each
    method (a biharmonic field, beating nearest on sparse cells) is in test_known_answers."""
    fill = BASELINES[name]
    z = rng.normal(-1.8, 0.5, (24, 24))
    known = rng.random((24, 24)) < 0.3
    out = fill(t(np.where(known, z, 0)), t(known))[0, 0].numpy()
    np.testing.assert_array_equal(out[known], z[known].astype(np.float32))
    assert np.isfinite(out).all()
    # a constant observed map is filled with that constant
    known = rng.random((24, 24)) < 0.3
    out = fill(t(np.where(known, -1.8, 0)), t(known))[0, 0].numpy()
    np.testing.assert_allclose(out, -1.8, atol=1e-4)
    # Row 0 and column 0 (which OpenCV 4 never fills by itself) are filled from their own
    # neighbours. A flat 3 m map with a 1 m pit observed in the middle: exactly 3 m there (an
    # unfilled border would come back as the lowest observed height, 2 m).
    pit = np.full((24, 24), 3.0)
    pit[12, 12] = 2.0
    known = np.ones((24, 24), bool)
    known[0, :] = known[:, 0] = False
    out = fill(t(np.where(known, pit, 0)), t(known))[0, 0].numpy()
    np.testing.assert_allclose(out[~known], 3.0, rtol=0, atol=1e-4)
    # A ramp along the border, 0.1 m per cell, with only that row (or column) unknown: measured
    # RMSE 4.4 mm (biharmonic), 0 (harmonic: a plane is discrete-harmonic where its
    # neighbours are known), 11-12 mm (Telea), 14 mm (Navier-Stokes); tolerance 20 mm. Values
    # taken one cell along the ramp are 0.1 m off (a crop shifted by one cell: 97-109 mm).
    ramp = plane((24, 24), a=0.0, b=0.1, c=3.0)
    for z, unknown in ((ramp, np.s_[0, :]), (ramp.T, np.s_[:, 0])):
        known = np.ones((24, 24), bool)
        known[unknown] = False
        out = fill(t(np.where(known, z, 0)), t(known))[0, 0].numpy()
        assert np.sqrt(np.mean((out[unknown] - z[unknown]) ** 2)) < 0.02, (name, unknown)


def test_opencv_fills_are_scale_free(rng):
    """The same map in metres and in millimetres: Telea's intensity-unit terms would show."""
    z = plane((24, 24)) + 0.05 * rng.standard_normal((24, 24))
    known = rng.random((24, 24)) < 0.3
    for name in ("telea", "ns"):
        metres = BASELINES[name](t(np.where(known, z, 0)), t(known))
        mm = BASELINES[name](t(np.where(known, 1000 * z, 0)), t(known))
        np.testing.assert_allclose(mm.numpy() / 1000, metres.numpy(), atol=1e-3, err_msg=name)


def test_every_baseline_on_empty_full_and_batched_maps(rng):
    z = rng.normal(0, 1, (3, 1, 16, 16)).astype(np.float32)
    mask = (rng.random((3, 1, 16, 16)) < 0.4).astype(np.float32)
    mask[0] = 0  # nothing observed: zeros
    mask[1] = 1  # everything observed: the scan
    scan, m = torch.from_numpy(z * mask), torch.from_numpy(mask)
    assert set(BASELINES) == {"nearest", "linear", "biharmonic", "harmonic", "telea", "ns", "plane"}
    for name, fill in BASELINES.items():
        out = fill(scan, m)
        assert out.shape == scan.shape and out.dtype == torch.float32, name
        assert torch.equal(out[0], torch.zeros_like(out[0])), name
        assert torch.equal(out[1], scan[1]), name
        assert torch.equal(out[2][m[2] > 0], scan[2][m[2] > 0]) and torch.isfinite(out).all(), name
    with pytest.raises(ValueError, match="shape"):
        BASELINES["plane"](scan[:, 0], m[:, 0])


# ------------------------------------------------------------------------------ test sets
def test_test_seeds_are_disjoint_from_training_and_validation_and_fixed():
    seeds = eval_seeds(64)
    assert seeds == [TEST_SEED_BASE + i for i in range(4)] == eval_seeds(64)
    assert TEST_SEED_BASE == 2**31 - 2**24 and eval_seeds(16 * 2**20)[-1] == TEST_SEED_BASE + 2**20 - 1
    with pytest.raises(ValueError, match="2\\*\\*24"):  # the last seed stays below generate_batch's 31-bit mask
        eval_seeds(16 * 2**24 + 1)
    # training: batch_seed is reduced modulo 2**30; validation: 2**30 + chunk index
    assert max(batch_seed(s, r, k) for s in range(3) for r in range(2) for k in range(50)) < VALIDATION_SEED_BASE <= min(seeds)
    assert validation_seed(2**30 - 2**24 - 1) < min(seeds)
    with pytest.raises(ValueError, match="size"):
        eval_seeds(0)


def test_test_sets_are_deterministic_and_nested():
    a = make_eval_set("octave3", 0.05, size=2, device="cpu")
    b = make_eval_set("octave3", 0.05, size=3, device="cpu")
    assert a.seeds == [TEST_SEED_BASE] and a.ground is None
    for key in ("scan", "mask", "target"):
        assert torch.equal(getattr(a, key), getattr(b, key)[:2]), key
    assert not setting_config("octave3", 0.05).data.augment


def _touched(diff_heights: np.ndarray, sim) -> np.ndarray:
    """Map cells within reach of a terrain vertex that changed (no augmentation)."""
    s, mc, tc = sim.data.map_size, sim.data.map_cell, sim.terrain.cell
    reach = int(math.ceil(0.5 * mc / tc)) + 1
    changed = ndimage.maximum_filter(diff_heights != 0, size=(1, 2 * reach + 1, 2 * reach + 1))
    size = diff_heights.shape[1]
    idx = np.rint((np.arange(s) - (s - 1) / 2) * mc / tc + (size - 1) / 2).astype(int)
    return changed[:, idx][:, :, idx]


@pytest.mark.parametrize("terrain,sign", [("flat_cylinders", 1.0), ("negative_obstacles", -1.0)])
def test_obstacle_free_twin_is_the_bare_terrain(terrain, sign):
    """Obstacles draw from their own random stream: the same seed without obstacles gives the
    same relief, sensor height and (augmentation) transform, so its target is the bare ground."""
    for augment in (False, True):
        sim = setting_config(terrain)
        sim.data.augment = augment
        full = generate_batch(2, sim, seed=TEST_SEED_BASE, device="cpu")
        bare = generate_batch(2, bare_config(sim), seed=TEST_SEED_BASE, device="cpu")
        assert bare_config(sim).terrain.has_obstacles() is False and sim.terrain.has_obstacles()
        assert torch.equal(full.sensor_z, bare.sensor_z)
        dh = (full.heights - bare.heights).numpy()
        dt = (full.target - bare.target)[:, 0].numpy()
        assert (dh != 0).mean() < 0.1 and (dh != 0).any()
        assert (sign * dh >= 0).all() and (sign * dt >= -1e-6).all()  # obstacles only raise / only cut
        # flat ground and pits that follow the terrain: each changed vertex moved by a whole obstacle height
        assert (np.abs(dh[dh != 0]) >= 0.5 - 1e-5).all()
        if not augment:
            touched = _touched(dh, sim)
            assert dh.shape[1] == terrain_size(sim)
            assert np.abs(dt[~touched]).max() < 1e-6  # identical wherever no obstacle reaches
            assert (np.abs(dt) > 1e-6).sum() > 20
            changed_plain = int((np.abs(dt) > 1e-6).sum())
        else:  # flips / rotations permute the cells but change nothing else
            assert int((np.abs(dt) > 1e-6).sum()) == changed_plain


# ------------------------------------------------------------------------------ models and the CLI
def test_model_predictor_and_checkpoint(tmp_path):
    from warp_terrain.models import ModelConfig, build_model

    torch.manual_seed(0)
    model = build_model(ModelConfig(name="unet", in_channels=2, ngf=4, ndf=4, unet_depth=3))
    scan = torch.randn(3, 1, 121, 121)
    mask = (torch.rand(3, 1, 121, 121) < 0.3).float()
    expected = model.predict(torch.cat([scan, mask], dim=1))
    out = model_predictor(model, 2, chunk=2)(scan, mask)
    assert out.shape == (3, 1, 121, 121)
    torch.testing.assert_close(out, expected)
    path = tmp_path / "best.pt"
    torch.save({"model": model.state_dict(), "step": 7, "config": {"model": {"in_channels": 2, "name": "unet"}}}, path)
    predictor = load_predictor(path, device="cpu", tta=False)
    info = predictor.info
    assert info["in_channels"] == 2 and info["step"] == 7 and not info["tta"]
    torch.testing.assert_close(predictor(scan, mask), expected)
    with pytest.raises(ValueError, match="does not exist"):
        load_predictor(tmp_path / "missing.pt")


def test_evaluate_cli_quick_json(tmp_path, capsys):
    md, figs = tmp_path / "eval.md", tmp_path / "figs"
    argv = ["evaluate", "--quick", "--size", "2", "--json", "--settings", "flat_cylinders", "--noise", "0",
            "--device", "cpu", "--markdown", str(md), "--figures", str(figs)]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["methods"] == list(BASELINES)
    (setting,) = out["settings"]
    assert setting["setting"] == "flat_cylinders/noise0" and setting["samples"] == 2
    assert setting["seeds"] == [TEST_SEED_BASE]
    for name in BASELINES:
        m = setting["metrics"][name]
        for key in ("rmse_unobserved", "mae_unobserved", "rmse_observed", "rmse_in_range", "obstacle_iou", "ms_per_map"):
            assert isinstance(m[key], float) and math.isfinite(m[key]), (name, key)
        assert "pit_recall" not in m
        assert out["ms_per_map"][name] > 0
    # every fill keeps the observed cells: the same observed-cell error for all of them
    assert len({round(setting["metrics"][n]["rmse_observed"], 9) for n in BASELINES}) == 1
    text = md.read_text()
    assert "| flat_cylinders/noise0 |" in text and "obstacle IoU" in text and "ms/map" in text
    assert (figs / "flat_cylinders_noise0.png").stat().st_size > 1000
    assert main(["evaluate", "--baselines", "nope"]) == 2
    assert main(["evaluate", "--settings", "nope", "--quick"]) == 2
    assert json_ready({"a": [float("nan"), 1.0]}) == {"a": [None, 1.0]}


def test_dem_patches_keep_the_real_slopes_and_are_deterministic():
    import matplotlib.cbook as cbook

    from warp_terrain.evaluation.robustness import DEM_PIXEL_M, dem_heightfields

    a = dem_heightfields(3, 65, 0.25, seed=2)
    b = dem_heightfields(3, 65, 0.25, seed=2)
    assert a.shape == (3, 65, 65) and a.dtype == np.float32 and np.array_equal(a, b)
    assert np.all(a[:, 32, 32] == 0.0)  # centred on the sensor's ground
    # the steepest grade of a patch never exceeds the DEM's own steepest grade
    dem = np.asarray(cbook.get_sample_data("jacksboro_fault_dem.npz")["elevation"], np.float64)
    dem_grade = max(np.abs(np.diff(dem, axis=0)).max(), np.abs(np.diff(dem, axis=1)).max()) / DEM_PIXEL_M
    patch_grade = max(np.abs(np.diff(a, axis=1)).max(), np.abs(np.diff(a, axis=2)).max()) / 0.25
    assert 0 < patch_grade <= dem_grade + 1e-6
