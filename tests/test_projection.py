"""Ground projection: exact cell means, masks, and what is ignored."""

import numpy as np
import pytest
import torch

import warp_terrain as wt


def test_points_land_in_the_cell_of_their_rounded_coordinates():
    S, c = 5, 0.5  # cells centred at -1, -0.5, 0, 0.5, 1 m
    pts = np.array(
        [
            [0.0, 0.0, 1.0],  # centre cell (2, 2)
            [0.2, -0.2, 3.0],  # still (2, 2): mean 2
            [1.0, -1.0, -1.0],  # corner cell (4, 0)
            [0.76, 0.0, 5.0],  # (4, 2): 0.76 / 0.5 + 2 = 3.52 -> 4
            [0.74, 0.0, 7.0],  # (3, 2)
            [1.3, 0.0, 9.0],  # off the map (index 4.6 -> 5)
            [np.nan, 0.0, 1.0],  # no return
            [0.0, np.inf, 1.0],  # broken
        ],
        dtype=np.float32,
    )
    height, mask = wt.project_points(pts, map_size=S, map_cell=c)
    assert height.shape == (1, 1, S, S) and mask.shape == (1, 1, S, S)
    expected_h = np.zeros((S, S), np.float32)
    expected_m = np.zeros((S, S), np.float32)
    for (i, j), z in {(2, 2): 2.0, (4, 0): -1.0, (4, 2): 5.0, (3, 2): 7.0}.items():
        expected_h[i, j], expected_m[i, j] = z, 1.0
    np.testing.assert_allclose(height[0, 0].numpy(), expected_h, atol=1e-6)
    np.testing.assert_array_equal(mask[0, 0].numpy(), expected_m)


def test_batched_points_stay_in_their_own_map():
    pts = torch.zeros(3, 4, 3)
    pts[:, :, 2] = torch.arange(3.0)[:, None]
    pts[1, :, :] = float("nan")
    height, mask = wt.project_points(pts, map_size=3, map_cell=1.0)
    assert mask[:, 0, 1, 1].tolist() == [1.0, 0.0, 1.0]
    assert height[:, 0, 1, 1].tolist() == [0.0, 0.0, 2.0]
    assert mask.sum() == 2


def test_huge_coordinates_are_ignored_not_wrapped():
    pts = np.array([[1e30, -1e30, 1.0], [3e9, 0.0, 1.0], [0.0, 0.0, 2.0]], np.float32)
    height, mask = wt.project_points(pts, map_size=3, map_cell=1.0)
    assert mask.sum() == 1 and height[0, 0, 1, 1] == 2.0


def test_empty_cloud_gives_an_empty_map():
    height, mask = wt.project_points(np.zeros((0, 3), np.float32), map_size=7)
    assert height.shape == (1, 1, 7, 7) and mask.sum() == 0


@pytest.mark.parametrize(
    "points, kwargs, name",
    [
        (np.zeros((4, 2)), {}, "points"),
        (np.zeros((2, 3, 4, 3)), {}, "points"),
        (np.zeros(3), {}, "points"),
        (np.zeros((4, 3)), dict(map_size=0), "map_size"),
        (np.zeros((4, 3)), dict(map_size=12.5), "map_size"),
        (np.zeros((4, 3)), dict(map_cell=0.0), "map_cell"),
        (np.zeros((4, 3)), dict(map_cell=-0.25), "map_cell"),
    ],
)
def test_bad_input_names_the_parameter(points, kwargs, name):
    with pytest.raises(ValueError, match=name):
        wt.project_points(points, **kwargs)
