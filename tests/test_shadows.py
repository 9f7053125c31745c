"""The scan's shadows (``inference/shadows.py``): the sensor's line of sight over observed cells."""

from __future__ import annotations

import math

import pytest
import torch

from warp_terrain.inference.shadows import horizon, ray_cells, shadow_cells

SIZE = 21  # centre cell (10, 10): distances along a row are whole cells


def ground(value: float = -1.8) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.full((1, 1, SIZE, SIZE), value), torch.zeros(1, 1, SIZE, SIZE)


def test_the_horizon_is_the_line_of_sight_over_the_observed_cell_in_front():
    """One observed cell 4 cells in front of the sensor at -0.5 m: along its ray the lowest
    visible height at 8 cells is -0.5 * 8 / 4 = -1.0 m, at 10 cells -1.25 m; lowered by a margin
    of 0.1 m the line passes through -0.6 m at 4 cells: -1.2 m at 8. Off its ray nothing bounds."""
    scan, mask = ground()
    scan[..., 10, 14], mask[..., 10, 14] = -0.5, 1.0
    h = horizon(scan * mask, mask)
    assert float(h[0, 0, 10, 18]) == pytest.approx(-1.0, abs=1e-6)
    assert float(h[0, 0, 10, 20]) == pytest.approx(-1.25, abs=1e-6)
    assert float(horizon(scan * mask, mask, 0.1)[0, 0, 10, 18]) == pytest.approx(-1.2, abs=1e-6)
    assert float(horizon(scan * mask, mask, torch.tensor(0.1).view(1, 1, 1, 1))[0, 0, 10, 18]) == pytest.approx(-1.2, abs=1e-6)
    for cell in ((10, 14), (10, 12), (10, 6), (14, 10), (0, 0), (10, 10)):  # the cell itself, in front, behind the sensor, other rays
        assert h[0, 0, cell[0], cell[1]] == -math.inf


def test_shadows_are_the_unobserved_cells_whose_fill_lies_under_the_horizon():
    """A 1 m wall across the ray at 5 cells, flat ground at -1.8 m behind it unobserved: the
    line over the wall's top (-0.8 m at 5 cells) meets the ground at 5 * 1.8 / 0.8 = 11.25
    cells, past the map's edge (10 cells): every unobserved cell behind the wall is in its
    shadow, none in front of it or beside it, and no observed cell ever is."""
    scan, mask = ground()
    mask[...] = 1.0
    scan[..., 9:12, 15] = -0.8
    mask[..., 9:12, 16:] = 0.0
    mask[..., 2:5, 2:5] = 0.0  # a gap in the open, nothing in front of it higher than the ground
    fill = scan.clone()
    fill[mask == 0] = -1.8
    shadows = shadow_cells(scan * mask, mask, fill)
    assert bool(shadows[..., 10, 16:].all())
    assert not bool(shadows[..., 2:5, 2:5].any()) and not bool(shadows[mask > 0].any())
    # a fill that stays as high as the wall is visible over it: no shadow where the fill is above the line
    high = fill.clone()
    high[..., 10, 16:] = -0.5
    assert not bool(shadow_cells(scan * mask, mask, high)[..., 10, 16:].any())


def test_each_cells_ray_holds_the_cells_between_it_and_the_centre_and_not_itself():
    index, distance = ray_cells(SIZE)
    assert index.shape[0] == SIZE * SIZE
    assert float(distance[10, 10]) == 0.0 and float(distance[10, 18]) == 8.0
    ray = set(index[10 * SIZE + 18].tolist()) - {SIZE * SIZE}
    assert ray == {10 * SIZE + c for c in range(11, 18)}  # the row's cells from the sensor's neighbour to the cell before
    diagonal = set(index[20 * SIZE + 20].tolist()) - {SIZE * SIZE}
    assert diagonal == {k * SIZE + k for k in range(11, 20)}
    for cell in range(SIZE * SIZE):  # never the cell itself
        assert cell not in set(index[cell].tolist())


def test_horizon_names_bad_shapes():
    scan, mask = ground()
    with pytest.raises(ValueError, match="horizon: need scan and mask of one shape"):
        horizon(scan, mask[..., :-1])
    with pytest.raises(ValueError, match="ray_cells: size must be an integer >= 1"):
        ray_cells(0)
