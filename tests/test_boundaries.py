"""Boundaries and exact answers of the metrics, the classical fills, the loss weights and output
paths: a cell exactly on a threshold or a radius, the fewest cells a method needs, per-map
normalisation, the method each fill names. Written against surviving mutants of `make mutation`."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from warp_terrain.core.paths import file_name, output_path
from warp_terrain.core.structs import build
from warp_terrain.evaluation.baselines import INPAINT_RADIUS, linear_fill, navier_stokes_fill, telea_fill
from warp_terrain.evaluation.metrics import calibration, error_metrics, obstacle_iou, pit_recall, range_cells
from warp_terrain.models.fill import fill_relative_weight, unobserved_weight_map
from warp_terrain.sim.terrain import TerrainConfig, TiltConfig


# ------------------------------------------------------------------------------ metrics
def test_range_cells_includes_cells_exactly_on_the_radius():
    # 5 cells of 0.5 m: centres at -1, -0.5, 0, 0.5, 1 m; radius 1 m holds 13 of them (x^2 + y^2 <= 1)
    assert int(range_cells(5, 0.5, 1.0).sum()) == 13
    # 0.1 m cells, radius 0.1 m: the four neighbours of the centre are on the circle in float64
    # (in float32 they fall outside: the centres are computed in float64)
    assert range_cells(3, 0.1, 0.1)[0, 0].tolist() == [[False, True, False], [True, True, True], [False, True, False]]
    assert range_cells(1, 0.25).tolist() == [[[[True]]]]  # one cell: the smallest map


@pytest.mark.parametrize(("args", "message"), [
    ((0, 0.25), "map_size=0: must be an integer >= 1"),
    ((2.5, 0.25), "map_size=2.5: must be an integer >= 1"),
    ((5, 0.0), "map_cell=0.0: must be a finite number > 0"),
    ((5, 0.25, 0.0), "max_range=0.0: must be > 0"),
])
def test_range_cells_refuses_bad_arguments_by_name(args, message):
    with pytest.raises(ValueError) as err:
        range_cells(*args)
    assert str(err.value) == message


def test_obstacles_and_pits_count_only_cells_strictly_beyond_the_threshold():
    ground = torch.zeros(1, 1, 1, 4)
    target = torch.tensor([0.25, 0.5, -0.25, -0.5]).view(1, 1, 1, 4)  # on the threshold, above, on, below
    # prediction: finds the 0.5 m obstacle, puts a 0.25 m one where the truth is 0.25 m (not an obstacle)
    prediction = torch.tensor([0.25, 0.5, -0.125, -0.25]).view(1, 1, 1, 4)
    assert obstacle_iou(prediction, target, ground, threshold=0.25) == 1.0  # only cell 1, in both
    # one pit cell (cell 3: 0.5 below); found where the prediction is more than 0.125 below: cell 3 is (0.25)
    assert pit_recall(prediction, target, ground, threshold=0.25) == 1.0
    shallow = prediction.clone()
    shallow[..., 3] = -0.125  # exactly half the threshold: not found
    assert pit_recall(shallow, target, ground, threshold=0.25) == 0.0
    for metric in (obstacle_iou, pit_recall):
        assert np.isnan(metric(ground, ground, ground, threshold=0.25))  # nothing to find
        with pytest.raises(ValueError) as err:
            metric(prediction, target, ground[..., :3], threshold=0.25)
        assert str(err.value) == "prediction (1, 1, 1, 4), target (1, 1, 1, 4) and ground (1, 1, 1, 3) must match"


def test_error_metrics_score_the_in_range_cells_given_and_name_a_mismatched_mask():
    target = torch.zeros(1, 1, 2, 2)
    prediction = torch.tensor([[1.0, 2.0], [3.0, 4.0]]).view(1, 1, 2, 2)
    mask = torch.tensor([[1.0, 0.0], [0.0, 0.0]]).view(1, 1, 2, 2)
    in_range = torch.tensor([[False, True], [False, True]]).view(1, 1, 2, 2)
    m = error_metrics(prediction, target, mask, in_range)
    assert m["mae_observed"] == 1.0 and m["mae_unobserved"] == 3.0
    assert m["mae_in_range"] == 3.0 and m["rmse_in_range"] == pytest.approx(10.0**0.5, rel=1e-12)  # cells 2 and 4
    assert error_metrics(prediction, target, mask)["mae_in_range"] == 2.5  # None: every cell
    with pytest.raises(ValueError) as err:
        error_metrics(prediction, target, mask[..., :1])
    assert str(err.value) == "prediction (1, 1, 2, 2), target (1, 1, 2, 2) and mask (1, 1, 2, 1) must match"


def test_calibration_counts_an_error_of_exactly_one_or_two_sigma_as_within():
    target = torch.zeros(1, 1, 1, 4)
    prediction = torch.tensor([0.5, 1.0, -2.0, 3.0]).view(1, 1, 1, 4)
    sigma = torch.tensor([1.0, 1.0, 1.0, 2.0]).view(1, 1, 1, 4)
    out = calibration(prediction, sigma, target, torch.ones(1, 1, 1, 4, dtype=torch.bool))
    assert out["within_1sigma"] == 0.5  # 0.5 and 1.0 (on the edge); not 2.0, not 3.0 (1.5 sigma)
    assert out["within_2sigma"] == 1.0  # -2.0 is exactly two sigma
    assert out["rms_sigma"] == pytest.approx(7.0**0.5 / 2.0, rel=1e-12)


def test_calibration_with_no_cell_is_nan_under_every_key_and_names_a_mismatched_sigma():
    z = torch.zeros(1, 1, 2, 2)
    out = calibration(z, z + 1.0, z, torch.zeros(1, 1, 2, 2, dtype=torch.bool))
    assert sorted(out) == ["rms_sigma", "within_1sigma", "within_2sigma"] and all(np.isnan(v) for v in out.values())
    with pytest.raises(ValueError) as err:
        calibration(z, z[..., :1], z, z > 0)
    assert str(err.value) == "prediction (1, 1, 2, 2), target (1, 1, 2, 2) and sigma (1, 1, 2, 1) must match"


# ------------------------------------------------------------------------------ classical fills
def test_linear_fill_reproduces_a_plane_from_exactly_three_cells():
    i, j = np.indices((9, 9), dtype=np.float64)
    plane = torch.from_numpy(0.3 * i - 0.2 * j + 1.5).float()[None, None]
    mask = torch.zeros(1, 1, 9, 9)
    mask[0, 0, 0, 0] = mask[0, 0, 0, 8] = mask[0, 0, 8, 0] = 1.0  # the triangle covers the upper-left half
    out = linear_fill(plane * mask, mask)[0, 0]
    inside = torch.from_numpy(i + j <= 8)
    torch.testing.assert_close(out[inside], plane[0, 0][inside], rtol=0, atol=1e-5)


def _opencv(z: np.ndarray, known: np.ndarray, flags: int) -> np.ndarray:
    """OpenCV's inpainting of heights as the fills document it: observed range onto 0..65535
    (at least 1 m), one hole cell padded all round, radius ``INPAINT_RADIUS``."""
    lo, span = z[known].min(), max(z[known].max() - z[known].min(), 1.0)
    img = np.pad(np.where(known, (z - lo) * 65535.0 / span, 0.0).astype(np.float32), 1)
    holes = np.pad((~known).astype(np.uint8), 1, constant_values=1)
    return cv2.inpaint(img, holes, float(INPAINT_RADIUS), flags)[1:-1, 1:-1].astype(np.float64) * span / 65535.0 + lo


def test_telea_and_navier_stokes_are_opencvs_methods_at_the_documented_radius():
    rng = np.random.default_rng(5)
    z = np.cumsum(rng.normal(size=(24, 24)), axis=0) * 0.3 + 40.0  # 40 m up, a few metres of relief
    known = rng.random((24, 24)) < 0.3
    scan, mask = torch.from_numpy(np.where(known, z, 0.0)).float()[None, None], torch.from_numpy(known).float()[None, None]
    z32 = scan[0, 0].double().numpy()
    for fill, flags, other in ((telea_fill, cv2.INPAINT_TELEA, cv2.INPAINT_NS), (navier_stokes_fill, cv2.INPAINT_NS, cv2.INPAINT_TELEA)):
        want = np.where(known, z32, _opencv(z32, known, flags))
        got = fill(scan, mask)[0, 0].double().numpy()
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-4)
        assert np.abs(got - np.where(known, z32, _opencv(z32, known, other))).max() > 0.01  # the other method differs


# ------------------------------------------------------------------------------ loss weights
def test_unobserved_weights_average_one_on_every_map():
    mask = torch.zeros(2, 1, 3, 5)
    mask[0, 0, 0, :] = 1.0  # 5 of 15 observed
    mask[1, 0, :, :4] = 1.0  # 12 of 15 observed
    w = unobserved_weight_map(mask, 3.0)
    assert w.shape == mask.shape
    torch.testing.assert_close(w.mean(dim=(1, 2, 3)), torch.ones(2), rtol=0, atol=1e-6)
    # map 0: observed 1, unobserved 3, mean (5 + 30) / 15 = 7/3
    torch.testing.assert_close(w[0, 0, 0, 0], torch.tensor(3.0 / 7.0), rtol=0, atol=1e-6)
    torch.testing.assert_close(w[0, 0, 1, 0], torch.tensor(9.0 / 7.0), rtol=0, atol=1e-6)


def test_fill_relative_weights_are_the_inverse_base_error_normalised():
    mask = torch.ones(3, 1, 4, 4)
    mask[:2, 0, 1:3, 1:3] = 0.0  # maps 0 and 1: four unobserved cells
    mask[2, 0, 0, 0] = 0.0  # map 2: a single unobserved cell
    target = torch.full((3, 1, 4, 4), 2.0)
    base = target.clone()
    base[0] += 0.1  # mean absolute error 0.1 on its unobserved cells
    base[1] -= 0.4  # 0.4
    base[2, 0, 0, 0] += 0.2  # 0.2, on one cell
    base[2, 0, 3, 3] += 9.0  # an observed cell: never counted
    w = fill_relative_weight(base, target, mask, floor=0.01).flatten()
    inverse = torch.tensor([10.0, 2.5, 5.0])
    torch.testing.assert_close(w, inverse / inverse.mean(), rtol=1e-5, atol=0)



def test_fill_relative_weights_by_the_median_ignore_a_few_deep_cells():
    """``statistic="median"``: a map whose fill is 2 cm off on most unobserved cells and metres off
    in two (a pit) weighs as a 2 cm map, where the mean would weigh it as a 0.71 m one; a map
    without unobserved cells gets its floor; an unknown statistic is refused by name."""
    mask = torch.ones(3, 1, 4, 4)
    mask[:2, 0, 0, :] = 0.0
    mask[:2, 0, 1, 0] = 0.0  # maps 0 and 1: five unobserved cells; map 2: none
    target = torch.zeros(3, 1, 4, 4)
    base = target.clone()
    base[0, 0, 0, :] = torch.tensor([0.02, -0.02, 1.5, -2.0])
    base[0, 0, 1, 0] = 0.02  # errors 0.02 x3, 1.5, 2.0: median 0.02, mean 0.712
    base[1] = 0.1  # every cell 0.1 m off: median = mean = 0.1
    base[0, 0, 3, 3] = 9.0  # an observed cell: never counted
    median = fill_relative_weight(base, target, mask, floor=0.01, statistic="median").flatten()
    inverse = torch.tensor([50.0, 10.0, 100.0])
    torch.testing.assert_close(median, inverse / inverse.mean(), rtol=1e-5, atol=0)
    mean = fill_relative_weight(base, target, mask, floor=0.01).flatten()
    inverse = torch.tensor([1 / 0.712, 10.0, 100.0])
    torch.testing.assert_close(mean, inverse / inverse.mean(), rtol=1e-5, atol=0)
    with pytest.raises(ValueError, match="'mode'.*mean, median"):
        fill_relative_weight(base, target, mask, floor=0.01, statistic="mode")


def test_fill_relative_weights_for_a_squared_loss_are_the_inverse_mean_squared_errors():
    """``power=2``: 1 / the base fill's mean squared error on the unobserved cells, normalised
    (and the floor squared): a map whose cells err by 0.1 and 0.3 m weighs 1 / 0.05, not 1 / 0.2."""
    mask = torch.ones(3, 1, 4, 4)
    mask[:, 0, 0, :2] = 0.0  # two unobserved cells per map
    target = torch.zeros(3, 1, 4, 4)
    base = target.clone()
    base[0, 0, 0, 0], base[0, 0, 0, 1] = 0.1, -0.3  # squared errors 0.01 and 0.09: mean 0.05
    base[1, 0, 0, 0] = 0.2  # 0.04 and 0: mean 0.02
    base[2, 0, 0, 0] = 0.001  # below the floor: 1 / 0.01 ** 2
    base[2, 0, 3, 3] = 5.0  # an observed cell: never counted
    w = fill_relative_weight(base, target, mask, floor=0.01, power=2).flatten()
    inverse = torch.tensor([20.0, 50.0, 1e4])
    torch.testing.assert_close(w, inverse / inverse.mean(), rtol=1e-5, atol=0)


# ------------------------------------------------------------------------------ output paths
def test_file_names_lose_only_leading_dots_and_unsafe_runs():
    assert file_name("XX.yaml") == "XX.yaml"
    assert file_name("..hidden") == "hidden"
    assert file_name("a b/c") == "a_b_c"
    assert file_name("...") == "_"


def test_output_path_names_the_escaping_part_and_the_folder(tmp_path):
    with pytest.raises(ValueError) as err:
        output_path(tmp_path, "..", "x.png")
    assert str(err.value) == f"{'../x.png'!r}: output path escapes its folder {str(tmp_path)!r}"
    assert output_path(tmp_path, "a", "b.png") == tmp_path / "a" / "b.png"


# ------------------------------------------------------------------------------ configs from any mapping
class _DuckMapping:
    """Keys and item access, not registered as a ``Mapping`` (as some config objects are)."""

    def __init__(self, data):
        self._data = data

    def keys(self):
        return self._data.keys()

    def __getitem__(self, key):
        return self._data[key]


def test_build_reads_any_object_with_keys_and_items_but_not_a_string():
    cfg = build(TerrainConfig, _DuckMapping({"octaves": 3, "tilt": _DuckMapping({"enabled": True})}))
    assert cfg.octaves == 3 and cfg.tilt.enabled is True and cfg.tilt.slope_max_deg == TerrainConfig().tilt.slope_max_deg

    class Keyless:
        def __getitem__(self, key):
            return 1

    for value in ("enabled", Keyless()):  # neither is a mapping: kept as the value given
        assert build(TerrainConfig, {"tilt": value}).tilt is value
    given = TiltConfig(enabled=True, slope_max_deg=12.0)  # a dataclass: a copy, never shared
    cfg = build(TerrainConfig, {"tilt": given})
    assert cfg.tilt == given and cfg.tilt is not given


def test_fills_refuse_a_scan_with_more_than_one_channel_naming_it():
    scan = torch.zeros(1, 2, 8, 8)
    with pytest.raises(ValueError, match=r"^scan: expected shape \(B, 1, H, W\), got \(1, 2, 8, 8\)$"):
        linear_fill(scan, torch.ones_like(scan))


def test_metrics_name_cells_of_the_wrong_shape():
    from warp_terrain.evaluation.metrics import masked_rmse

    with pytest.raises(ValueError) as err:
        masked_rmse(torch.zeros(1, 1, 4, 4), torch.zeros(1, 1, 4, 4), torch.ones(1, 1, 3, 3, dtype=torch.bool))
    assert str(err.value) == "prediction (1, 1, 4, 4), target (1, 1, 4, 4) and cells (1, 1, 3, 3) must match"
