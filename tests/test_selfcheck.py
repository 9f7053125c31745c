"""The self-check: a map keeps the share of the net's correction its own scan supports."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from warp_terrain.inference import reconstructor as reconstructor_module
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.inference.selfcheck import (
    CHECK_SHARE,
    REACH_FAR,
    REACH_NEAR,
    SIGMA_COVERAGE,
    SIGMA_MIN_CELLS,
    SIGMA_RESOLUTION,
    best_fill,
    correction_weight,
    far_share,
    hidden_cells,
    outer_cells,
    pick,
    resolved_sigma_factor,
    scan_noise,
    sigma_factor,
)
from warp_terrain.models.config import ModelConfig
from warp_terrain.models.fill import FillResidualGenerator


def test_hidden_cells_are_a_fixed_share_of_the_observed_ones():
    mask = (torch.rand(2, 1, 121, 121, generator=torch.Generator().manual_seed(1)) < 0.4).float()
    hidden = hidden_cells(mask)
    assert torch.equal(hidden, hidden_cells(mask))  # the same scan, the same check
    assert not (hidden & (mask == 0)).any()
    share = float(hidden.sum() / mask.sum())
    assert abs(share - CHECK_SHARE) < 0.01


def test_a_maps_hidden_cells_do_not_depend_on_its_batch():
    masks = (torch.rand(5, 1, 121, 121, generator=torch.Generator().manual_seed(2)) < 0.4).float()
    together = hidden_cells(masks)
    for i in range(5):  # alone, or anywhere in another batch: the same cells
        assert torch.equal(hidden_cells(masks[i:i + 1]), together[i:i + 1])
    assert torch.equal(hidden_cells(masks.flip(0)), together.flip(0))
    assert torch.equal(hidden_cells(masks[:, 0]), together[:, 0])  # (B, S, S) masks too


def test_correction_weight_is_the_least_squares_share_clamped():
    fill = torch.zeros(4, 1, 8, 8)
    d = torch.randn(4, 1, 8, 8, generator=torch.Generator().manual_seed(2))
    hidden = torch.zeros(4, 1, 8, 8, dtype=torch.bool)
    hidden[..., ::2, ::3] = True
    model = fill + d
    measured = torch.stack([0.5 * d[0], torch.zeros_like(d[1]), 2.0 * d[2], -d[3]])
    w = correction_weight(model, fill, measured, hidden).flatten()
    torch.testing.assert_close(w, torch.tensor([0.5, 0.0, 1.0, 0.0]), rtol=0, atol=1e-6)
    assert correction_weight(fill, fill, measured, hidden).abs().max() == 0  # no correction: weight 0


def test_a_small_correction_gets_its_exact_weight():
    """Centimetre corrections on four hidden cells (sum of squares 4e-4 m^2, far below 1): the
    weight is still the least-squares one, not cut to zero or shrunk by a floor on the sum."""
    fill = torch.zeros(1, 1, 4, 4)
    hidden = torch.zeros(1, 1, 4, 4, dtype=torch.bool)
    hidden[..., 1:3, 1:3] = True
    model = fill + 0.01
    measured = fill + 0.005
    torch.testing.assert_close(correction_weight(model, fill, measured, hidden).flatten(), torch.tensor([0.5]), rtol=0, atol=1e-6)


def test_best_fill_picks_per_map_the_candidate_that_errs_least_on_hidden_cells():
    measured = torch.stack([torch.full((1, 4, 4), 1.0), torch.full((1, 4, 4), -0.3)])
    hidden = torch.ones(2, 1, 4, 4, dtype=torch.bool)
    hidden[:, :, 0, 0] = False  # a kept cell: what a candidate does there does not count
    a = torch.stack([torch.full((1, 4, 4), 0.8), torch.full((1, 4, 4), 0.5)])  # candidate 0 per map: 0.2 and 0.8 off
    b = torch.stack([torch.full((1, 4, 4), 1.1), torch.full((1, 4, 4), -0.2)])  # candidate 1 per map: 0.1 and 0.1 off
    b[0, 0, 0, 0] = a[1, 0, 0, 0] = 100.0
    choice = best_fill(torch.stack([a, b]), measured, hidden)
    assert choice.tolist() == [1, 1]
    choice = best_fill(torch.stack([b, a]), measured, hidden)
    assert choice.tolist() == [0, 0]
    torch.testing.assert_close(pick(torch.stack([a, b]), torch.tensor([0, 1])), torch.stack([a[0], b[1]]))


@pytest.mark.parametrize("base", ["plane_biharmonic", "biharmonic", "push_pull"])
def test_base_and_plain_fills_are_each_maps_base_its_thin_plate_and_its_membrane_in_one_solve(base, monkeypatch):
    """The fills the check weighs: each map's base fill (as ``base_fill`` alone computes it),
    then the plain fill of the first ``count`` maps under each tension; with a thin-plate base
    all of them in a single solve, whatever the maps solved beside them."""
    import warp_terrain.models.fill as fill_module
    from warp_terrain.models.biharmonic import biharmonic_fill
    from warp_terrain.models.fill import observed_plane, push_pull_fill

    g = torch.Generator().manual_seed(3)
    scan = torch.randn(3, 1, 24, 24, generator=g) + torch.linspace(0, 4, 24)  # a tilt: the plane base differs
    mask = (torch.rand(3, 1, 24, 24, generator=g) < 0.3).float()
    scan = scan * mask
    generator = FillResidualGenerator(Offset(0.0), base=base)
    solves, plain_solve = [], fill_module.biharmonic_fills
    monkeypatch.setattr(fill_module, "biharmonic_fills", lambda problems: solves.append(sum(h.shape[0] for h, _, _ in problems)) or plain_solve(problems))
    bases, plain = generator.base_and_plain_fills(scan, mask, (0.0, 1.0), count=2)
    assert solves == ([3 + 2 * 2] if base != "push_pull" else [2 * 2])  # one solve
    assert bases.shape == (3, 1, 24, 24) and plain.shape == (2, 2, 1, 24, 24)
    plane = observed_plane(scan, mask)
    want = {"plane_biharmonic": lambda: biharmonic_fill(scan - plane, mask) + plane,
            "biharmonic": lambda: biharmonic_fill(scan, mask), "push_pull": lambda: push_pull_fill(scan, mask)}[base]()
    torch.testing.assert_close(bases, want, rtol=0, atol=1e-5)  # the base fill, solved beside the plain ones
    torch.testing.assert_close(generator.base_fill(scan, mask), want, rtol=0, atol=1e-5)
    for b in range(2):  # a map's fills do not depend on the maps solved beside it, nor on their tension
        torch.testing.assert_close(plain[0, b:b + 1], biharmonic_fill(scan[b:b + 1], mask[b:b + 1]), rtol=0, atol=1e-5)
        torch.testing.assert_close(plain[1, b:b + 1], biharmonic_fill(scan[b:b + 1], mask[b:b + 1], tension=1.0), rtol=0, atol=1e-5)
    assert (plain[0] - plain[1]).abs().max() > 0.1  # two different fills
    if base == "plane_biharmonic":
        assert (bases[:2] - plain[0]).abs().max() > 1e-3  # the base fill is not the plain thin plate
    alone, none = generator.base_and_plain_fills(scan, mask)
    assert torch.equal(alone, generator.base_fill(scan, mask)) and none.shape == (0, 3, 1, 24, 24)
    _, one = generator.base_and_plain_fills(scan, mask, tensions=(0.5,))
    torch.testing.assert_close(one[0], biharmonic_fill(scan, mask, tension=0.5), rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="tension must be in"):
        biharmonic_fill(scan, mask, tension=torch.tensor([0.0, 1.0, 2.0]).view(3, 1, 1, 1))


def test_the_generator_given_its_own_base_fill_returns_what_it_computes():
    g = torch.Generator().manual_seed(4)
    scan = torch.randn(2, 1, 32, 32, generator=g)
    mask = (torch.rand(2, 1, 32, 32, generator=g) < 0.3).float()
    generator = FillResidualGenerator(torch.nn.Conv2d(2, 1, 3, padding=1), base="plane_biharmonic", reference="plane").eval()
    condition = torch.cat([scan * mask, mask], dim=1)
    with torch.no_grad():
        want = generator(condition)
        assert torch.equal(generator(condition, fill=generator.base_fill(scan * mask, mask)), want)
        assert not torch.equal(generator(condition, fill=torch.zeros_like(scan)), want)  # the fill given is the one used


class Offset(torch.nn.Module):
    """A 'net' whose correction is a constant (in the generator's scaled units)."""

    def __init__(self, value: float):
        super().__init__()
        self.value = value

    def forward(self, x):
        return torch.full_like(x[:, :1], self.value)


def plane_scan(size: int = 48):
    r, c = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    z = (0.02 * r - 0.01 * c - 1.8)[None, None]
    mask = ((r + 2 * c) % 5 == 0).float()[None, None]
    return z * mask, mask, z


def reconstructor(value: float, self_check: bool, check_reach: bool = False, check_keep_far: bool = False) -> Reconstructor:
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, base_fill="plane_biharmonic", height_reference="plane")
    generator = FillResidualGenerator(Offset(value), base="plane_biharmonic", reference="plane")
    return Reconstructor(generator, cfg, device="cpu", tta=False, self_check=self_check, check_reach=check_reach,
                         check_keep_far=check_keep_far)


def test_a_correction_the_scan_refutes_is_switched_off():
    """On a plane every classical fill is right; a model that lifts the map by 1 m is wrong on
    the hidden cells, so the checked map is the fill (the plane), the unchecked one 1 m off."""
    scan, mask, truth = plane_scan()
    unchecked = reconstructor(1.0, self_check=False).predict_maps(scan, mask)
    torch.testing.assert_close(unchecked, truth + 1.0, rtol=0, atol=1e-4)  # the plane fill of a plane is exact
    checked = reconstructor(1.0, self_check=True).predict_maps(scan, mask)
    assert float((checked - truth).abs().max()) < 0.01


def test_a_correction_the_scan_supports_is_kept():
    """The fill of a scan whose hidden cells sit 0.3 m above the plane errs there; a model
    that adds exactly 0.3 m everywhere is right on them and is kept whole."""
    scan, mask, truth = plane_scan()
    hidden = hidden_cells(mask)
    raised = scan + 0.3 * hidden.float()
    checked = reconstructor(0.3, self_check=True).predict_maps(raised, mask)
    unchecked = reconstructor(0.3, self_check=False).predict_maps(raised, mask)
    np.testing.assert_allclose(checked.numpy(), unchecked.numpy(), rtol=0, atol=1e-5)


def test_package_model_records_the_self_check_and_refuses_it_without_a_fill(tmp_path):
    import pytest

    from warp_terrain.evaluation.calibrate import package_model
    from warp_terrain.models.pix2pix import build_generator

    for residual, name in ((True, "residual.pt"), (False, "plain.pt")):
        cfg = ModelConfig(name="unet", in_channels=2, residual=residual, ngf=4, unet_depth=3).validate()
        Reconstructor(build_generator(cfg), cfg, device="cpu").save(tmp_path / name)
    out = package_model(tmp_path / "residual.pt", tmp_path / "checked.pt", calibrate=0, self_check=True)
    assert out["self_check"] is True
    assert Reconstructor.load(tmp_path / "checked.pt", device="cpu").self_check
    assert not Reconstructor.load(tmp_path / "checked.pt", device="cpu", self_check=False).self_check
    assert not Reconstructor.load(tmp_path / "residual.pt", device="cpu").self_check  # off unless the file says so
    with pytest.raises(ValueError, match="self_check needs a fill-residual model"):
        package_model(tmp_path / "plain.pt", tmp_path / "x.pt", calibrate=0, self_check=True)
    assert not (tmp_path / "x.pt").exists()


def test_the_shipped_model_checks_itself_near_and_far_from_the_scan():
    shipped = Reconstructor.load(device="cpu")
    assert shipped.self_check and shipped.check_reach and shipped.check_keep_far
    assert not Reconstructor.load(device="cpu", check_keep_far=False).check_keep_far
    assert not Reconstructor.load(device="cpu", self_check=False).self_check
    assert not Reconstructor.load(device="cpu", check_reach=False).check_reach


def test_the_shipped_models_checked_map_does_not_depend_on_its_batch():
    """The check's cells, fills and weights are per map: a map predicted alone equals the same
    map predicted among others, to float rounding."""
    shipped = Reconstructor.load(device="cpu", tta=False)
    g = torch.Generator().manual_seed(3)
    size = 48
    r, c = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    tilt = torch.rand(3, 2, 1, 1, generator=g) - 0.5
    truth = (0.05 * tilt[:, :1] * r + 0.05 * tilt[:, 1:] * c + 0.3 * torch.sin(0.2 * r) * torch.cos(0.15 * c))[:, :1]
    mask = (torch.rand(3, 1, size, size, generator=g) < 0.3).float()
    together = shipped.predict_maps(truth * mask, mask)
    for i in range(3):
        alone = shipped.predict_maps(truth[i:i + 1] * mask[i:i + 1], mask[i:i + 1])
        torch.testing.assert_close(alone, together[i:i + 1], rtol=0, atol=1e-4)


def test_far_share_is_the_chessboard_distance_ramp():
    """0 up to REACH_NEAR cells from an observed cell, 1 from REACH_FAR on, linear between."""
    mask = torch.zeros(2, 1, 21, 21)
    mask[0, 0, 10, 10] = 1.0  # map 1 has no observed cell: far everywhere
    share = far_share(mask)
    r, c = torch.meshgrid(torch.arange(21), torch.arange(21), indexing="ij")
    chessboard = torch.maximum((r - 10).abs(), (c - 10).abs()).float()
    expected = ((chessboard - REACH_NEAR) / (REACH_FAR - REACH_NEAR)).clamp(0, 1)
    torch.testing.assert_close(share[0, 0], expected, rtol=0, atol=1e-6)
    assert float(share[0, 0, 10, 10 + REACH_NEAR]) == 0.0 and float(share[0, 0, 10, 10 + REACH_FAR]) == 1.0
    assert bool((share[1] == 1.0).all())
    assert bool((far_share(torch.ones(1, 1, 5, 5)) == 0.0).all())
    for near, far in ((2, 2), (3, 1), (-1, 4), (1.5, 4)):
        with pytest.raises(ValueError, match="near"):
            far_share(mask, near, far)


def test_outer_cells_are_the_observed_cells_farthest_from_the_sensor():
    """A ring of cells at radius 3 and one at radius 10 around the centre, observed: with a
    share just over the outer ring's, the outer ring (and only it) is selected."""
    size = 31
    axis = torch.arange(size, dtype=torch.float32) - 15
    radius = torch.sqrt(axis[:, None] ** 2 + axis[None, :] ** 2)
    inner, outer = (radius - 3).abs() < 0.5, (radius - 10).abs() < 0.5
    mask = (inner | outer).float()[None, None]
    share = float(outer.sum()) / float(mask.sum()) + 0.01
    picked = outer_cells(mask, share)[0, 0]
    assert bool((picked == outer).all())
    assert not bool(outer_cells(torch.zeros(1, 1, 9, 9)).any())  # nothing observed: nothing hidden


def test_far_share_takes_near_zero_and_keeps_a_floating_masks_dtype():
    mask = torch.zeros(1, 1, 11, 11, dtype=torch.float64)
    mask[0, 0, 5, 5] = 1.0
    share = far_share(mask, 0, 4)  # near = 0: the ramp starts at the observed cell
    assert share.dtype == torch.float64
    assert [float(share[0, 0, 5, 5 + k]) for k in range(6)] == [0.0, 0.25, 0.5, 0.75, 1.0, 1.0]
    assert far_share(mask.bool()).dtype == torch.float32 and far_share(mask.half()).dtype == torch.float16


def _cells(size: int, *offsets: tuple[int, int]) -> torch.Tensor:
    """(1, 1, size, size) mask observed at the given (row, column) offsets from the centre."""
    mask = torch.zeros(1, 1, size, size)
    c = size // 2
    for dr, dc in offsets:
        mask[0, 0, c + dr, c + dc] = 1.0
    return mask


def test_outer_cells_measure_from_the_map_centre_per_map():
    """Two cells on one row, 5 and 4 cells from the centre, on either side, and the same mirrored
    on a second map: the farther one of each map is picked (a centre off by half a cell or one
    picks the wrong one), each map by its own cut (one cut over the batch would pick two of one
    map's cells and none of the other's)."""
    mask = torch.cat([_cells(21, (0, 5), (0, -4)), _cells(21, (0, 4), (0, -5))])
    picked = outer_cells(mask, 0.5)
    assert picked.shape == mask.shape
    assert picked[0, 0, 10].nonzero().flatten().tolist() == [15] and picked[1, 0, 10].nonzero().flatten().tolist() == [5]
    assert int(picked.sum()) == 2
    # map 1's cells all lie inside map 0's: still its own farthest cell is picked
    wide = torch.cat([_cells(21, (0, 9), (0, 8), (0, 1)), _cells(21, (0, 2), (0, 1), (1, 0))])
    assert outer_cells(wide, 0.34).sum(dim=(1, 2, 3)).tolist() == [1, 1]


def test_outer_cells_never_hide_more_than_their_share():
    """Four cells at radius 3 and four at radius 5: the outermost quarter's cut falls on radius 5
    itself, and cells at the cut are kept: at most ``share`` of the observed cells are hidden."""
    mask = _cells(21, (3, 0), (-3, 0), (0, 3), (0, -3), (5, 0), (-5, 0), (0, 5), (0, -5))
    assert int(outer_cells(mask, 0.25).sum()) == 0
    assert int(outer_cells(mask, 0.6).sum()) == 4  # the cut between the rings: the outer ring


def test_check_reach_falls_back_far_from_the_scan_where_the_outer_cells_refute_the_model():
    """A +1 m correction on an exact plane: the near check and the far check (the scan's outer
    cells hidden) both refute it, so with ``check_reach`` the map is the plane everywhere, far
    from the scan too."""
    scan, mask, truth = plane_scan()
    mask[..., 16:] = 0.0  # the scan covers the first 16 columns only: the rest is far from it
    scan = scan * mask
    reach = reconstructor(1.0, self_check=True, check_reach=True).predict_maps(scan, mask)
    assert float((reach - truth).abs().max()) < 0.01
    unchecked = reconstructor(1.0, self_check=False, check_reach=True).predict_maps(scan, mask)
    torch.testing.assert_close(unchecked, truth + 1.0, rtol=0, atol=1e-3)  # no self-check: no reach


def test_check_reach_keeps_a_correction_the_outer_cells_support_far_from_the_scan():
    """The scan's outer cells (``outer_cells``) sit 0.3 m above the plane of its inner cells and
    the model adds 0.3 m: refuted on the inner hidden cells (w_near = 0), right on the outer
    ones (w_far = 1). So the map is the fill next to the scan, the model's far from it, and
    ``fill + far_share 0.3 m`` everywhere (the model's map minus ``0.3 (1 - far_share)``)."""
    scan, mask, truth = plane_scan()
    mask[..., 16:] = 0.0
    outer = outer_cells(mask)
    assert 0 < int(outer.sum()) < int(mask.sum())
    scan = (truth + 0.3 * outer.float()) * mask
    unchecked = reconstructor(0.3, self_check=False).predict_maps(scan, mask)
    reach = reconstructor(0.3, self_check=True, check_reach=True).predict_maps(scan, mask)
    share = far_share(mask)
    torch.testing.assert_close(reach, unchecked - 0.3 * (1.0 - share), rtol=0, atol=2e-3)
    far = share == 1
    assert bool(far[..., 16 + REACH_FAR - 1:].all())
    torch.testing.assert_close(reach[far], unchecked[far], rtol=0, atol=2e-3)
    # with keep_far the far weight is 1 whatever it measured, and the near one still the near check's (0)
    kept = reconstructor(0.3, self_check=True, check_reach=True, check_keep_far=True).predict_maps(scan, mask)
    torch.testing.assert_close(kept, unchecked - 0.3 * (1.0 - share), rtol=0, atol=2e-3)


def test_keep_far_keeps_the_correction_whole_far_from_the_scan_whatever_the_outer_cells_say():
    """The refuted +1 m correction of the test above, with ``check_keep_far``: the near check
    still switches it off next to the scan (w_near = 0), but far from it the correction is kept
    whole (w_far = 1 although the outer cells refute it): the map is the plane plus
    ``far_share`` metres, exactly the blend of the near and the kept far weight."""
    scan, mask, truth = plane_scan()
    mask[..., 16:] = 0.0
    scan = scan * mask
    kept = reconstructor(1.0, self_check=True, check_reach=True, check_keep_far=True).predict_maps(scan, mask)
    share = far_share(mask)
    torch.testing.assert_close(kept, truth + share, rtol=0, atol=2e-3)
    assert bool((share[..., 16 + REACH_FAR - 1:] == 1).all()) and bool((share[mask > 0] == 0).all())
    # without the reach there is no far weight to keep: the check alone, the plane everywhere
    plain = reconstructor(1.0, self_check=True, check_keep_far=True).predict_maps(scan, mask)
    assert float((plain - truth).abs().max()) < 0.01


def _save_tiny_residual(path) -> None:
    """A small untrained fill-residual model file for the packaging tests."""
    from warp_terrain.models.pix2pix import build_generator

    cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=4, unet_depth=3).validate()
    Reconstructor(build_generator(cfg), cfg, device="cpu").save(path)


def test_package_model_records_check_reach_and_needs_the_self_check(tmp_path):
    from warp_terrain.evaluation.calibrate import package_model

    cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=4, unet_depth=3).validate()
    from warp_terrain.models.pix2pix import build_generator

    Reconstructor(build_generator(cfg), cfg, device="cpu").save(tmp_path / "residual.pt")
    out = package_model(tmp_path / "residual.pt", tmp_path / "reach.pt", calibrate=0, self_check=True, check_reach=True)
    assert out["check_reach"] is True
    loaded = Reconstructor.load(tmp_path / "reach.pt", device="cpu")
    assert loaded.self_check and loaded.check_reach
    assert not Reconstructor.load(tmp_path / "reach.pt", device="cpu", check_reach=False).check_reach
    assert not Reconstructor.load(tmp_path / "residual.pt", device="cpu").check_reach  # off unless the file says so
    with pytest.raises(ValueError, match="check_reach: needs self_check"):
        package_model(tmp_path / "residual.pt", tmp_path / "x.pt", calibrate=0, self_check=False, check_reach=True)
    assert not (tmp_path / "x.pt").exists()
    assert not loaded.check_keep_far  # off unless asked
    out = package_model(tmp_path / "residual.pt", tmp_path / "far.pt", calibrate=0, self_check=True, check_reach=True,
                        check_keep_far=True)
    assert out["check_keep_far"] is True and Reconstructor.load(tmp_path / "far.pt", device="cpu").check_keep_far
    with pytest.raises(ValueError, match="check_keep_far: needs check_reach"):
        package_model(tmp_path / "residual.pt", tmp_path / "x.pt", calibrate=0, self_check=True, check_keep_far=True)
    assert not (tmp_path / "x.pt").exists()


def test_package_model_records_check_sigma_and_refuses_it_without_a_head_or_the_check(tmp_path):
    from warp_terrain.evaluation.calibrate import package_model
    from warp_terrain.models.pix2pix import build_generator

    for uncertainty in (True, False):
        cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=4, unet_depth=3, uncertainty=uncertainty).validate()
        Reconstructor(build_generator(cfg), cfg, device="cpu").save(tmp_path / f"u{uncertainty}.pt")
    out = package_model(tmp_path / "uTrue.pt", tmp_path / "sigma.pt", calibrate=0, self_check=True, check_sigma=True, check_membrane=True)
    assert out["check_sigma"] is True and Reconstructor.load(tmp_path / "sigma.pt", device="cpu").check_sigma
    assert out["check_membrane"] is True and Reconstructor.load(tmp_path / "sigma.pt", device="cpu").check_tensions == (0.0, 1.0)
    with pytest.raises(ValueError, match="check_membrane: needs self_check"):
        package_model(tmp_path / "uTrue.pt", tmp_path / "x.pt", calibrate=0, check_membrane=True)
    assert not Reconstructor.load(tmp_path / "sigma.pt", device="cpu", check_sigma=False).check_sigma
    assert not Reconstructor.load(tmp_path / "uTrue.pt", device="cpu").check_sigma  # off unless the file says so
    with pytest.raises(ValueError, match="check_sigma: needs self_check"):
        package_model(tmp_path / "uTrue.pt", tmp_path / "x.pt", calibrate=0, check_sigma=True)
    with pytest.raises(ValueError, match="check_sigma needs a model with an uncertainty head"):
        package_model(tmp_path / "uFalse.pt", tmp_path / "x.pt", calibrate=0, self_check=True, check_sigma=True)
    assert not (tmp_path / "x.pt").exists()


def test_sigma_factor_puts_the_coverage_share_of_the_checked_cells_within_k_sigma():
    """Errors of 0.01, 0.02, ..., 1.00 m on 100 checked cells with sigma 0.5 m: k sigma must be
    the 68.27 % quantile of the errors (torch's linear interpolation: 0.6859 m), so k = 1.3718;
    cells not checked do not count, and a map with too few checked cells keeps k = 1."""
    measured = torch.zeros(2, 1, 10, 12)
    predicted = torch.zeros_like(measured)
    predicted[0, 0, :, :10] = torch.arange(1, 101, dtype=torch.float32).view(10, 10) / 100
    predicted[0, 0, :, 10:] = 50.0  # wild cells outside the checked ones
    cells = torch.zeros_like(measured, dtype=torch.bool)
    cells[0, 0, :, :10] = True
    cells[1, 0, 0, :5] = True  # 5 cells: below SIGMA_MIN_CELLS
    sigma = torch.full_like(measured, 0.5)
    k = sigma_factor(predicted, sigma, measured, cells).flatten()
    torch.testing.assert_close(k, torch.tensor([0.68590 / 0.5, 1.0]), rtol=0, atol=1e-4)
    inside = ((predicted - measured).abs() <= k.view(-1, 1, 1, 1) * sigma)[0][cells[0]]
    assert int(inside.sum()) == 68  # 68 of the 100 cells lie within the scaled sigma
    assert SIGMA_MIN_CELLS > 5 and 0.68 < SIGMA_COVERAGE < 0.69


def test_sigma_factor_takes_the_measurements_own_noise_out_of_the_checked_errors():
    """A measured height errs by the scan's noise ``n``: cells whose checked error is
    ``sqrt(n^2 + (r sigma)^2)`` for r = 0.01 ... 1.00 have ground errors ``r sigma``, so k is the
    68.27 % quantile of r (0.6859), not of the checked errors over sigma; an error below the
    noise counts as no error; ``noise = 0`` is the plain factor."""
    sigma, n = 0.5, 0.3
    r = torch.arange(1, 101, dtype=torch.float32).view(1, 1, 10, 10) / 100
    measured = torch.zeros_like(r)
    predicted = torch.sqrt(n**2 + (r * sigma) ** 2)
    cells = torch.ones_like(r, dtype=torch.bool)
    sig = torch.full_like(r, sigma)
    noise = torch.full((1, 1, 1, 1), n)
    torch.testing.assert_close(sigma_factor(predicted, sig, measured, cells, noise=noise).flatten(), torch.tensor([0.6859]), rtol=0, atol=1e-4)
    plain = sigma_factor(predicted, sig, measured, cells).flatten()
    torch.testing.assert_close(plain, torch.quantile((predicted / sigma).flatten(), SIGMA_COVERAGE).view(1), rtol=0, atol=1e-5)
    assert torch.equal(sigma_factor(predicted, sig, measured, cells, noise=torch.zeros(1, 1, 1, 1)), sigma_factor(predicted, sig, measured, cells))
    quiet = sigma_factor(torch.full_like(r, 0.2), sig, measured, cells, noise=noise)  # every error within the noise
    assert float(quiet) == 1.0  # nothing the check can resolve: the file's own sigma


def test_sigma_factor_keeps_the_files_sigma_where_the_noise_hides_the_maps_error():
    """100 checked cells with noise n = 0.3 m: the checked errors' quantile must stand
    SIGMA_RESOLUTION standard errors (n / sqrt(100) each) above n for the check to measure the
    map's error; 1.1 n does not (k = 1, not the near-zero sqrt(1.21 - 1) n / sigma it would give),
    1.3 n does (k = sqrt(1.69 - 1) n / sigma exactly); without a noise every error is measured."""
    assert SIGMA_RESOLUTION == 2.0
    n, sigma = 0.3, 0.5
    measured = torch.zeros(2, 1, 10, 10)
    predicted = torch.cat([torch.full((1, 1, 10, 10), 1.1 * n), torch.full((1, 1, 10, 10), 1.3 * n)])
    cells = torch.ones_like(measured, dtype=torch.bool)
    sig = torch.full_like(measured, sigma)
    k = sigma_factor(predicted, sig, measured, cells, noise=torch.full((2, 1, 1, 1), n)).flatten()
    torch.testing.assert_close(k, torch.tensor([1.0, 0.69**0.5 * n / sigma]), rtol=0, atol=1e-5)
    torch.testing.assert_close(sigma_factor(predicted, sig, measured, cells).flatten(), torch.tensor([1.1, 1.3]) * n / sigma)
    fewer = cells.clone()
    fewer[:, :, 5:] = False
    fewer[:, :, :, 5:] = False  # 25 cells: the quantile errs more, 1.3 n no longer stands out (1 + 2 / sqrt(25) = 1.4)
    assert torch.equal(sigma_factor(predicted, sig, measured, fewer, noise=torch.full((2, 1, 1, 1), n)).flatten(), torch.ones(2))
    # a file's fallback for the maps the check cannot resolve replaces the 1, and only there
    k, resolved = resolved_sigma_factor(predicted, sig, measured, cells, noise=torch.full((2, 1, 1, 1), n))
    assert resolved.tolist() == [False, True]
    torch.testing.assert_close(k.flatten(), torch.tensor([1.0, 0.69**0.5 * n / sigma]), rtol=0, atol=1e-6)
    fallen = sigma_factor(predicted, sig, measured, cells, noise=torch.full((2, 1, 1, 1), n), fallback=0.4).flatten()
    torch.testing.assert_close(fallen, torch.tensor([0.4, 0.69**0.5 * n / sigma]), rtol=0, atol=1e-6)


def test_scan_noise_is_zero_on_planes_and_the_deviation_of_independent_noise():
    """Second differences vanish on any plane, a wall's step included (it moves only the few
    differences across it, not their median); on a plane with independent Gaussian noise of
    0.05 and 0.2 m (every cell observed, or every other cell of a ring-like pattern) the
    estimate is that deviation within 4 %; a map with no three observed cells in a line is 0."""
    size = 121
    r, c = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    plane = (0.3 * r - 0.2 * c + 5.0) * 0.25
    wall = plane + 2.0 * (c > 60)
    full = torch.ones(1, 1, size, size)
    clean = scan_noise(torch.stack([plane, wall])[:, None], full.expand(2, -1, -1, -1)).flatten()
    torch.testing.assert_close(clean, torch.zeros(2), rtol=0, atol=1e-5)
    g = torch.Generator().manual_seed(4)
    rings = ((r.long() // 3) % 2 == 0).float()[None, None]  # three rows observed, three not
    for deviation in (0.05, 0.2):
        noisy = plane + deviation * torch.randn(size, size, generator=g)
        for mask in (full, rings):
            estimate = float(scan_noise((noisy * mask[0, 0])[None, None], mask))
            assert abs(estimate / deviation - 1.0) < 0.04, (deviation, estimate)
    dots = ((r.long() % 2 == 0) & (c.long() % 2 == 0)).float()[None, None]
    assert float(scan_noise(plane[None, None] * dots, dots)) == 0.0
    assert float(scan_noise(plane[None, None] * 0, torch.zeros(1, 1, size, size))) == 0.0


def test_check_sigma_on_a_noisy_scan_covers_the_ground_not_the_noise(monkeypatch):
    """A plane scanned with 0.1 m noise, a 'net' that adds nothing and claims sigma = 1 m: the
    checked errors hold the noise of the hidden measurements; taken out (``scan_noise``), 60-75 %
    of the unobserved cells' errors against the true plane lie within 1 sigma; left in, the sigma
    is the noise's and covers far more."""
    size = 64
    r, c = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    truth = (0.02 * r - 0.01 * c - 1.8)[None, None].repeat(4, 1, 1, 1)
    g = torch.Generator().manual_seed(3)
    mask = (torch.rand(4, 1, size, size, generator=g) < 0.5).float()
    scan = (truth + 0.1 * torch.randn(truth.shape, generator=g)) * mask
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, base_fill="plane_biharmonic", height_reference="plane", uncertainty=True)
    generator = FillResidualGenerator(Constant(0.0, 0.0), base="plane_biharmonic", reference="plane")
    rec = Reconstructor(generator, cfg, device="cpu", tta=False, self_check=True, check_reach=True, check_sigma=True)
    unobserved = mask == 0

    def coverage():
        height, sigma = rec.predict_maps_with_uncertainty(scan, mask)
        return float(((height - truth).abs() <= sigma)[unobserved].float().mean()), float(sigma[unobserved].mean())

    covered, sigma = coverage()
    assert 0.60 <= covered <= 0.75
    monkeypatch.setattr(reconstructor_module, "scan_noise", lambda scan, mask: torch.zeros(scan.shape[0], 1, 1, 1))
    covered_with_noise, sigma_with_noise = coverage()
    assert covered_with_noise > 0.85 and sigma_with_noise > 1.4 * sigma


class Constant(torch.nn.Module):
    """A 'net' whose correction is a constant and whose log-variance is ``log_variance``."""

    def __init__(self, value: float, log_variance: float):
        super().__init__()
        self.value, self.log_variance = value, log_variance

    def forward(self, x):
        return torch.cat([torch.full_like(x[:, :1], self.value), torch.full_like(x[:, :1], self.log_variance)], dim=1)


def test_check_sigma_scales_each_maps_sigma_to_its_checked_errors():
    """A 'net' that lifts a plane by 0.3 m and claims sigma = 1 m: the check refutes the lift (the
    map is the plane, its error on hidden cells about 0), and the per-map factor shrinks the
    sigma to those errors; without ``check_sigma`` the claimed 1 m stays."""
    scan, mask, truth = plane_scan()
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, base_fill="plane_biharmonic", height_reference="plane", uncertainty=True)

    def rec(check_sigma):
        g = FillResidualGenerator(Constant(0.3, 0.0), base="plane_biharmonic", reference="plane")
        return Reconstructor(g, cfg, device="cpu", tta=False, self_check=True, check_reach=True, check_sigma=check_sigma)

    height, plain = rec(False).predict_maps_with_uncertainty(scan, mask)
    _, scaled = rec(True).predict_maps_with_uncertainty(scan, mask)
    assert float((height - truth).abs().max()) < 0.01
    torch.testing.assert_close(plain, torch.ones_like(plain), rtol=0, atol=1e-6)
    assert float(scaled.max()) < 0.01 and float(scaled.min()) > 0


def test_the_fallback_sigma_is_fitted_on_the_maps_the_check_cannot_resolve(monkeypatch):
    """Two calibration maps: a plane the check resolves (its errors about 0) and a sparse scan of
    a bump whose check has fewer than SIGMA_MIN_CELLS hidden cells in each regime. The fallback
    factor is ``sigma_scale`` times the 68.27 % quantile of |error| / sigma over the sparse map's
    unobserved cells alone; with it in the file the sparse map's sigma is that factor times the
    raw sigma, and the plane's stays as the check scaled it."""
    from warp_terrain.evaluation import calibrate

    plane, plane_mask, plane_truth = plane_scan()
    r, c = torch.meshgrid(torch.arange(48, dtype=torch.float32), torch.arange(48, dtype=torch.float32), indexing="ij")
    bump = (plane_truth[0, 0] + 0.5 * torch.exp(-((r - 30) ** 2 + (c - 20) ** 2) / 50.0))[None, None]
    sparse_mask = torch.zeros_like(plane_mask)
    sparse_mask[0, 0, ::12, ::12] = 1.0  # 16 cells: 3 hidden at random, 5 outer
    pairs = {"scan": torch.cat([plane, bump * sparse_mask]), "mask": torch.cat([plane_mask, sparse_mask]),
             "target": torch.cat([plane_truth, bump])}
    monkeypatch.setattr(calibrate, "make_pair", lambda sim, n, seed, device: {k: v[:n] for k, v in pairs.items()})
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, base_fill="plane_biharmonic", height_reference="plane", uncertainty=True)
    g = FillResidualGenerator(Constant(0.3, 0.0), base="plane_biharmonic", reference="plane")
    rec = Reconstructor(g, cfg, {"sigma_scale": 2.0}, device="cpu", tta=False, self_check=True, check_reach=True, check_sigma=True)
    before_height, before_sigma = rec.predict_maps_with_uncertainty(pairs["scan"], pairs["mask"])
    torch.testing.assert_close(before_sigma[1], torch.full_like(before_sigma[1], 2.0))  # unresolved: the file's sigma_scale
    unobserved = pairs["mask"][1] <= 0
    ratio = ((before_height[1] - pairs["target"][1]).abs() / before_sigma[1])[unobserved]
    expected = 2.0 * float(torch.quantile(ratio.double(), SIGMA_COVERAGE))
    fitted = calibrate.fit_unresolved_sigma_scale(rec, None, size=2)
    assert fitted == pytest.approx(expected, rel=1e-6)
    rec.meta["sigma_scale_unresolved"] = fitted
    assert rec.unresolved_sigma_factor == pytest.approx(fitted / 2.0)
    _, after_sigma = rec.predict_maps_with_uncertainty(pairs["scan"], pairs["mask"])
    torch.testing.assert_close(after_sigma[1], torch.full_like(after_sigma[1], fitted))
    torch.testing.assert_close(after_sigma[0], before_sigma[0], rtol=0, atol=0)  # resolved: the check's own factor
    assert float(before_sigma[0].max()) < 0.1  # the plane's sigma was scaled to its tiny checked errors
    only_plane = {k: v[:1] for k, v in pairs.items()}
    monkeypatch.setattr(calibrate, "make_pair", lambda sim, n, seed, device: only_plane)
    assert calibrate.fit_unresolved_sigma_scale(rec, None, size=1) is None  # nothing unresolved to fit on
    with pytest.raises(ValueError, match="needs a model that checks its sigma"):
        calibrate.fit_unresolved_sigma_scale(Reconstructor(g, cfg, device="cpu", tta=False, self_check=True), None)


def test_the_check_moves_the_fill_towards_the_membrane_by_the_share_the_scan_supports():
    """On a scan whose hidden cells are each the mean of their neighbours (a membrane's world),
    the checked fill is the membrane; on a plane scan the thin plate and the membrane agree only
    where the plane is harmonic, and the check keeps the plane (the thin plate reproduces it)."""
    from warp_terrain.models.biharmonic import biharmonic_fill

    scan, mask, truth = plane_scan()
    rec = reconstructor(0.0, self_check=True)
    assert rec.check_tensions == (0.0,)  # a file that does not name the membrane checks without it
    rec.check_tensions = (0.0, 1.0)
    torch.testing.assert_close(rec.predict_maps(scan, mask), truth, rtol=0, atol=2e-3)
    # the membrane's own world: observed heights drawn from a membrane fill of sparse anchors
    g = torch.Generator().manual_seed(9)
    anchors = (torch.rand(1, 1, 48, 48, generator=g) < 0.02).float()
    world = biharmonic_fill(torch.randn(1, 1, 48, 48, generator=g) * anchors, anchors, tension=1.0)
    membrane_mask = torch.maximum(anchors, (torch.rand(1, 1, 48, 48, generator=g) < 0.3).float())
    out = rec.predict_maps(world * membrane_mask, membrane_mask)
    thin_plate = biharmonic_fill(world * membrane_mask, membrane_mask)
    unobserved = membrane_mask == 0
    assert float((out - world)[unobserved].square().mean()) < 0.2 * float((thin_plate - world)[unobserved].square().mean())
    no_membrane = reconstructor(0.0, self_check=True)
    assert float((no_membrane.predict_maps(world * membrane_mask, membrane_mask) - world)[unobserved].abs().max()) > 0.01


def test_package_model_cli_passes_every_check_flag(tmp_path, capsys):
    """``warp-terrain package-model`` with each check flag writes a file that asks for it."""
    import json

    from warp_terrain.cli import main
    from warp_terrain.models.pix2pix import build_generator

    _save_tiny_residual(tmp_path / "residual.pt")
    args = ["package-model", str(tmp_path / "residual.pt"), "--out", str(tmp_path / "all.pt"), "--calibrate", "0", "--self-check",
            "--check-reach", "--check-membrane", "--check-keep-far"]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["check_reach"] and report["check_membrane"] and report["check_keep_far"] and not report["check_sigma"]
    rec = Reconstructor.load(tmp_path / "all.pt", device="cpu")
    assert rec.self_check and rec.check_reach and rec.check_keep_far and rec.check_membrane and not rec.check_sigma
    assert report["observed_bound_noise"] == 0.0 and rec.generator.noise_bound == 0.0  # as the checkpoint's model

    # the bound on observed cells widened by the scan's noise: the same weights, the config and the generator's bound changed
    assert main(["package-model", str(tmp_path / "residual.pt"), "--out", str(tmp_path / "x.pt"), "--calibrate", "0",
                 "--observed-bound-noise", "3"]) == 2
    assert "observed_bound_noise=3.0: needs model.observed_bound > 0" in capsys.readouterr().err
    assert not (tmp_path / "x.pt").exists()
    bounded = ModelConfig(name="unet", in_channels=2, residual=True, ngf=4, unet_depth=3, observed_bound=0.1).validate()
    Reconstructor(build_generator(bounded), bounded, device="cpu").save(tmp_path / "bounded.pt")
    assert main(["package-model", str(tmp_path / "bounded.pt"), "--out", str(tmp_path / "noise.pt"), "--calibrate", "0",
                 "--observed-bound-noise", "3"]) == 0
    assert json.loads(capsys.readouterr().out)["observed_bound_noise"] == 3.0
    widened, source = Reconstructor.load(tmp_path / "noise.pt", device="cpu"), Reconstructor.load(tmp_path / "bounded.pt", device="cpu")
    assert widened.model_config.observed_bound_noise == 3.0 and widened.generator.noise_bound == 3.0
    state = source.generator.state_dict()
    assert all(torch.equal(v, state[k]) for k, v in widened.generator.state_dict().items())


def _push_pull_reconstructor(tensions) -> Reconstructor:
    """A zero correction over the push-pull fill (which bends a smooth surface into steps): the
    check can only choose among the classical fills."""
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, base_fill="push_pull")
    rec = Reconstructor(FillResidualGenerator(Offset(0.0), base="push_pull"), cfg, device="cpu", tta=False, self_check=True)
    rec.check_tensions = tensions
    return rec


def _bowl_scan(size: int = 40):
    """A smooth bowl seen on a sparse lattice: the thin plate follows it, push-pull does not."""
    r, c = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    z = (0.002 * ((r - 17.0) ** 2 + (c - 22.0) ** 2) + 0.01 * r)[None, None]
    mask = ((r % 3 == 0) & (c % 3 == 0)).float()[None, None]
    return z * mask, mask, z


def test_the_check_picks_the_thin_plate_where_it_beats_the_base_fill():
    """Without the membrane, the checked map of a zero correction is the better of the base fill
    and the thin plate on the hidden cells: here the thin plate, exactly (the map the check
    returns is the full scan's thin plate, not the base fill)."""
    from warp_terrain.models.biharmonic import biharmonic_fill

    scan, mask, truth = _bowl_scan()
    thin_plate = biharmonic_fill(scan, mask)
    base = FillResidualGenerator(Offset(0.0), base="push_pull").base_fill(scan, mask)
    unobserved = mask == 0
    assert float((base - truth)[unobserved].abs().mean()) > 3 * float((thin_plate - truth)[unobserved].abs().mean())
    checked = _push_pull_reconstructor((0.0,)).predict_maps(scan, mask)
    torch.testing.assert_close(checked, thin_plate, rtol=0, atol=1e-5)


def test_with_the_membrane_the_thin_plate_is_still_a_smooth_candidate():
    """With the membrane among the fills, the smooth fill is still chosen among the base fill and
    the thin plate (then moved towards the membrane by the share the hidden cells support): on
    the bowl, which the membrane sags under, the map stays within 10 % of the thin plate's error
    and far below the base fill's."""
    from warp_terrain.models.biharmonic import biharmonic_fill

    scan, mask, truth = _bowl_scan()
    unobserved = mask == 0

    def rmse(m):
        return float(((m - truth)[unobserved] ** 2).mean().sqrt())

    thin_plate = rmse(biharmonic_fill(scan, mask))
    base = rmse(FillResidualGenerator(Offset(0.0), base="push_pull").base_fill(scan, mask))
    checked = rmse(_push_pull_reconstructor((0.0, 1.0)).predict_maps(scan, mask))
    assert checked <= 1.1 * thin_plate and checked < 0.5 * base


def test_the_membrane_moves_the_smooth_fill_but_is_not_one_of_the_smooth_candidates():
    """A bowl under 12 cm of noise: on the hidden cells the membrane errs least, the thin plate
    next. The smooth fill is still the thin plate (the membrane is no candidate for it), moved
    towards the membrane by a least-squares share strictly between 0 and 1: the map is
    about ``thin plate + beta (membrane - thin plate)`` (the fills as the check solves them: the
    scan and its thinned copy in one batch), not the membrane itself."""
    _, mask, truth = _bowl_scan()
    generator = torch.Generator().manual_seed(3)
    scan = (truth + 0.12 * torch.randn(truth.shape, generator=generator)) * mask
    rec = _push_pull_reconstructor((0.0, 1.0))
    thinned = mask * (~hidden_cells(mask)).to(mask.dtype)
    both_scans, both_masks = torch.cat([scan, scan * thinned]), torch.cat([mask, thinned])
    bases, plain = rec.generator.base_and_plain_fills(both_scans, both_masks, (0.0, 1.0))
    fills = torch.cat([bases[None], plain])
    hidden = hidden_cells(mask)
    errors = [float((((f[1:] - scan) * hidden) ** 2).sum()) for f in fills]  # the thinned scan's fills
    assert errors[2] < errors[1] < errors[0]  # membrane, thin plate, base
    thin_plate, membrane = fills[1, :1], fills[2, :1]
    out = rec.predict_maps(scan, mask)
    step = membrane - thin_plate
    beta = float(((out - thin_plate) * step).sum() / (step * step).sum())
    assert 0.05 < beta < 0.95
    # the rest is the (small) share of the net's map, here the push-pull base, the check also keeps
    residual = (out - thin_plate - beta * step).pow(2).mean().sqrt()
    assert float(residual) < 0.2 * float(step.pow(2).mean().sqrt())


def test_the_thinned_map_is_moved_towards_the_membrane_and_weighs_the_correction():
    """``checked_maps`` by hand: the thin plate (0) beats the base fill (5) on the hidden cells,
    where the scan measured 0.5 and the membrane says 1, so the membrane's share is exactly 1/2
    and the thinned map's fill is 0.5 there, right: the net's correction (+1 on the thinned map)
    then has weight 0, and both maps are the fills moved half-way to the membrane. A thinned map
    moved towards any other fill (the thin plate) would leave an error the correction's weight
    (1/3) would then take up."""
    from warp_terrain.inference.selfcheck import Regimes, checked_maps

    size = 8
    mask = torch.ones(1, 1, size, size)
    hidden = torch.zeros(1, 1, size, size, dtype=torch.bool)
    hidden[..., 1::3, 2::3] = True
    thinned = mask * (~hidden).to(mask.dtype)
    scan = torch.full((1, 1, size, size), 0.5)
    ramp = torch.linspace(0.0, 0.3, size).view(1, 1, 1, size).expand(1, 1, size, size)
    base, thin_plate, membrane = 5.0 + ramp, ramp * 0.0, torch.ones(1, 1, size, size)
    # each candidate of the full scan, then of the thinned one (as ``Reconstructor._predict`` stacks them)
    fills = torch.stack([torch.cat([f + 0.1, f]) for f in (base, thin_plate, membrane)])
    fills[1, :1] = -0.2  # the full scan's thin plate differs from the thinned one's
    model = torch.cat([torch.full_like(scan, 2.0), torch.full_like(scan, 1.5)])
    full, thinned_map = checked_maps(fills, model, scan, mask, thinned, Regimes(hidden, None), membrane=True, keep_far=False)
    torch.testing.assert_close(thinned_map, torch.full_like(scan, 0.5), rtol=0, atol=1e-6)
    torch.testing.assert_close(full, 0.5 * (fills[1, :1] + fills[2, :1]), rtol=0, atol=1e-6)


def test_the_check_measures_each_masks_distance_to_the_scan_once(monkeypatch):
    """The far shares of the full mask and of the thinned one are computed once per check, both
    in one batched call (the check blends with them five times), and the maps are those of a
    fresh share each time."""
    import warp_terrain.inference.selfcheck as selfcheck

    scan, mask, _ = plane_scan()
    rec = reconstructor(0.05, self_check=True, check_reach=True)
    rec.check_tensions = (0.0, 1.0)
    expected = rec.predict_maps(scan, mask)
    calls = []
    plain = selfcheck.far_share

    def counted(observed, *args, **kwargs):
        calls.append(observed)
        return plain(observed, *args, **kwargs)

    monkeypatch.setattr(selfcheck, "far_share", counted)
    assert torch.equal(rec.predict_maps(scan, mask), expected)
    assert len(calls) == 1 and calls[0].shape[0] == 2 * mask.shape[0] and torch.equal(calls[0][:1], mask)
    assert not torch.equal(calls[0][:1], calls[0][1:])  # the full mask, then the thinned one


def test_a_pair_of_weights_holds_at_each_cell_by_the_maps_far_share():
    """``Regimes.at``: ``near (1 - far) + away far`` per cell, ``far = far_share(mask)``: the near
    weight next to the scan, the away one beyond the reach, the blend in between; no away weight
    (no reach) is the near one everywhere."""
    from warp_terrain.inference.selfcheck import Regimes, far_share

    mask = torch.zeros(2, 1, 40, 40)
    mask[0, :, :5, :5] = 1.0
    mask[1, :, :, :3] = 1.0
    near = torch.tensor([0.3, -0.2], dtype=torch.float64).view(2, 1, 1, 1)
    away = torch.tensor([0.8, 1.5], dtype=torch.float64).view(2, 1, 1, 1)
    regimes = Regimes(torch.zeros_like(mask), torch.zeros_like(mask))
    got = regimes.at((near, away), mask)
    far = far_share(mask).double()
    assert ((far > 0) & (far < 1)).any() and (far == 0).any() and (far == 1).any()
    assert got.dtype == torch.float64
    torch.testing.assert_close(got, near * (1 - far) + away * far, rtol=0, atol=1e-12)
    torch.testing.assert_close(got[far == 0], near.expand_as(got)[far == 0], rtol=0, atol=0)
    torch.testing.assert_close(got[far == 1], away.expand_as(got)[far == 1], rtol=0, atol=0)
    assert regimes.at((near, None), mask) is near


def test_the_check_weighs_thin_plates_finished_by_v_cycles_and_leaves_the_membrane():
    """A bowl seen on three wide rings: the cascade stops short of the thin plate between them.
    With ``check_cycles`` the check's thin plates (of the scan and of its thinned copy) get that
    many V-cycles: a zero correction over push-pull, which the check refutes, returns the full
    scan's thin plate finished by exactly those cycles, nearer the direct solve than without;
    the membrane is not touched (the cascade nearly finishes it)."""
    from test_biharmonic import exact_fill, wide_rings

    from warp_terrain.models.biharmonic import biharmonic_fill, v_cycles

    size = 48
    r, c = torch.meshgrid(torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij")
    truth = (0.002 * ((r - 20.0) ** 2 + (c - 26.0) ** 2) + 0.01 * r)[None, None]
    mask = torch.from_numpy(wide_rings(size, 2)).float()[None, None]
    scan = truth * mask
    exact = torch.from_numpy(exact_fill(scan[0, 0].numpy().astype(np.float64), mask[0, 0].numpy() > 0, 0.0)).float()
    cascade = biharmonic_fill(scan, mask)
    free = mask == 0
    rec = _push_pull_reconstructor((0.0,))
    assert rec.check_cycles == 0  # a file that does not name them checks without them
    torch.testing.assert_close(rec.predict_maps(scan, mask), cascade, rtol=0, atol=1e-5)
    rec.check_cycles = 3
    checked = rec.predict_maps(scan, mask)
    torch.testing.assert_close(checked, v_cycles(cascade, mask, 3), rtol=0, atol=1e-5)
    assert float((checked - exact)[free].abs().max()) < 0.5 * float((cascade - exact)[free].abs().max())

    plain = torch.stack([cascade, biharmonic_fill(scan, mask, tension=1.0)])
    cycled = rec._cycled(plain, mask, (0.0, 1.0))
    torch.testing.assert_close(cycled[0], v_cycles(cascade, mask, 3), rtol=0, atol=0)
    assert torch.equal(cycled[1], plain[1]) and not torch.equal(cycled[0], plain[0])


def test_package_model_records_check_cycles_and_refuses_bad_ones(tmp_path, capsys):
    import json

    from warp_terrain.cli import main
    from warp_terrain.evaluation.calibrate import package_model

    _save_tiny_residual(tmp_path / "residual.pt")
    assert main(["package-model", str(tmp_path / "residual.pt"), "--out", str(tmp_path / "cycles.pt"), "--calibrate", "0",
                 "--self-check", "--check-cycles", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["check_cycles"] == 2
    assert Reconstructor.load(tmp_path / "cycles.pt", device="cpu").check_cycles == 2
    assert Reconstructor.load(tmp_path / "cycles.pt", device="cpu", check_cycles=0).check_cycles == 0
    assert Reconstructor.load(tmp_path / "residual.pt", device="cpu").check_cycles == 0
    with pytest.raises(ValueError, match="check_cycles: needs self_check"):
        package_model(tmp_path / "residual.pt", tmp_path / "x.pt", calibrate=0, check_cycles=1)
    with pytest.raises(ValueError, match="check_cycles=-1: must be an integer >= 0"):
        package_model(tmp_path / "residual.pt", tmp_path / "x.pt", calibrate=0, self_check=True, check_cycles=-1)
    assert not (tmp_path / "x.pt").exists()
    with pytest.raises(ValueError, match="check_cycles must be an integer >= 0"):
        Reconstructor.load(tmp_path / "residual.pt", device="cpu", check_cycles=-2)


def _walled_scan(size: int = 41, overhang: bool = False):
    """Flat ground at -1.8 m seen all round a sensor at the map's centre, a 1 m wall 8 cells in
    front of it and the ground behind the wall unobserved (its shadow); with ``overhang`` the
    ground behind the wall was seen all the same (returns under a canopy: a 2.5-D map puts them
    in the wall's shadow)."""
    from warp_terrain.inference.shadows import horizon

    centre = size // 2
    scan, mask = torch.full((1, 1, size, size), -1.8), torch.ones(1, 1, size, size)
    scan[..., centre - 3 : centre + 4, centre + 8] = -0.8
    if not overhang:  # the wall's shadow: the ground under the line of sight over it (tests/test_shadows.py)
        mask[scan < horizon(scan, mask)] = 0.0
    truth = scan.clone()
    return scan * mask, mask, truth


def _check_parts(scan, mask, correction: float):
    """The check's inputs for fills that are the truth (flat ground and the wall) and a net that
    adds ``correction`` metres everywhere off the observed cells: the hidden cells refute it."""
    from warp_terrain.inference.selfcheck import Regimes, check_cells, checked_maps

    hidden, _, thinned = check_cells(mask, reach=False)
    fill = torch.where(mask > 0, scan, torch.full_like(scan, -1.8))
    fill_thinned = torch.where(thinned > 0, scan, torch.full_like(scan, -1.8))
    fill_thinned = torch.where((mask > 0) & (scan > -1.0), scan, fill_thinned)  # the fills know the wall
    both = torch.cat([fill, fill_thinned])
    fills = torch.stack([both, both, both])  # base fill, thin plate, membrane: all the truth
    model = both + correction * (torch.cat([mask, thinned]) <= 0)
    regimes = Regimes(hidden, None)
    return lambda margin: checked_maps(fills, model, scan, mask, thinned, regimes, True, False, margin), fill


def test_the_check_keeps_the_correction_whole_in_the_scans_shadows():
    """The hidden cells refute the net's +0.5 m (they are the fill's exactly), so the check
    switches it off, except, with a shadow margin, on the cells behind the wall: the sensor saw
    nothing there, no hidden cell can measure the net there, and the map keeps all of it."""
    from warp_terrain.inference.shadows import shadow_cells

    scan, mask, _ = _walled_scan()
    check, fill = _check_parts(scan, mask, 0.5)
    off, _ = check(None)
    torch.testing.assert_close(off, fill)
    on, _ = check(torch.zeros(2, 1, 1, 1))
    shadows = shadow_cells(scan, mask, fill)
    assert torch.equal(shadows, mask <= 0)
    # the line over the wall's top (-0.8 m at 8 cells) meets the ground at 8 * 1.8 / 0.8 = 18 cells
    assert bool(shadows[0, 0, 20, 29:38].all()) and not bool(shadows[0, 0, 20, 38:].any())
    torch.testing.assert_close(on, fill + 0.5 * shadows)


def test_a_scan_whose_seen_cells_lie_in_its_shadows_refutes_its_horizon():
    """Returns behind the wall (under an overhang): the check's hidden cells there lie in the
    thinned scan's shadows although the sensor saw them, ``SHADOW_REFUTED`` or more of them, and
    they refute the +0.5 m: the shadows then keep their least-squares weight, none of it."""
    from warp_terrain.inference.selfcheck import SHADOW_REFUTED, check_cells
    from warp_terrain.inference.shadows import shadow_cells

    scan, mask, _ = _walled_scan(overhang=True)
    hidden, _, thinned = check_cells(mask, reach=False)
    seen_in_shadow = shadow_cells(scan * thinned, thinned, torch.full_like(scan, -1.8)) & hidden
    assert int(seen_in_shadow.sum()) >= SHADOW_REFUTED
    mask_cut = mask.clone()
    mask_cut[..., 19:22, 29:] = 0.0  # the shadow itself unobserved too, beside the seen cells
    check, fill = _check_parts(scan * mask_cut, mask_cut, 0.5)
    on, _ = check(torch.zeros(2, 1, 1, 1))
    torch.testing.assert_close(on, fill)


@pytest.mark.parametrize("setting", ["check_keep_shadows", "check_keep_large"])
def test_package_model_records_a_keep_setting_and_needs_the_self_check(tmp_path, capsys, setting):
    import json

    from warp_terrain.cli import main
    from warp_terrain.evaluation.calibrate import package_model

    _save_tiny_residual(tmp_path / "residual.pt")
    assert main(["package-model", str(tmp_path / "residual.pt"), "--out", str(tmp_path / "kept.pt"), "--calibrate", "0",
                 "--self-check", "--" + setting.replace("_", "-")]) == 0
    assert json.loads(capsys.readouterr().out)[setting] is True
    assert getattr(Reconstructor.load(tmp_path / "kept.pt", device="cpu"), setting)
    assert not getattr(Reconstructor.load(tmp_path / "kept.pt", device="cpu", **{setting: False}), setting)
    assert not getattr(Reconstructor.load(tmp_path / "residual.pt", device="cpu"), setting)  # off unless the file says so
    with pytest.raises(ValueError, match=f"{setting}: needs self_check"):
        package_model(tmp_path / "residual.pt", tmp_path / "x.pt", calibrate=0, **{setting: True})
    assert not (tmp_path / "x.pt").exists()


def _pit_check(dig_hidden: bool):
    """A flat ground at -1.8 m seen all round but for a 5 x 5 pit the sensor did not see; the fills
    are the flat ground. The net digs 0.5 m in the pit, adds 5 cm on the other unobserved cells of
    each map (the check's hidden cells among them: they are the fill's exactly, so it is refuted)
    and 0.5 m on one observed cell; with ``dig_hidden`` it digs 0.5 m on the hidden cells too."""
    from warp_terrain.inference.selfcheck import LARGE_CORRECTION, Regimes, check_cells, checked_maps

    size = 41
    mask = torch.ones(1, 1, size, size)
    mask[..., 8:13, 26:31] = 0.0
    scan = torch.full_like(mask, -1.8) * mask
    hidden, _, thinned = check_cells(mask, reach=False)
    fill = torch.full((2, 1, size, size), -1.8)
    fills = torch.stack([fill, fill, fill])
    pit = torch.zeros_like(mask, dtype=torch.bool)
    pit[..., 8:13, 26:31] = True
    both_masks = torch.cat([mask, thinned])
    correction = torch.where(both_masks <= 0, 0.05, 0.0)
    correction = torch.where(pit.repeat(2, 1, 1, 1), -0.5, correction)
    correction[:, :, 30, 5] = 0.5  # observed in both maps
    if dig_hidden:
        correction[1:] = torch.where(hidden, -0.5, correction[1:])
    model = fill + correction
    regimes = Regimes(hidden, None)
    maps = {large: checked_maps(fills, model, scan, mask, thinned, regimes, True, False, None, large)[0]
            for large in (None, LARGE_CORRECTION)}
    return maps, fill[:1], pit, int(hidden.sum())


def test_the_check_keeps_a_large_correction_whole_where_its_cells_cannot_measure_one():
    """The hidden cells refute the net's 5 cm, so the check switches its correction off; with
    ``large`` the pit's 0.5 m is kept whole (no hidden cell carries a correction that large), the
    5 cm and the observed cell's 0.5 m are not (only unobserved cells keep a large correction)."""
    maps, fill, pit, _ = _pit_check(dig_hidden=False)
    torch.testing.assert_close(maps[None], fill)
    torch.testing.assert_close(maps[0.3], fill - 0.5 * pit)


def test_large_corrections_on_the_checks_own_cells_are_measured_there():
    """The net digs 0.5 m on the hidden cells too (``LARGE_REFUTED`` or more of them), where the
    ground is the fill's: their least-squares weight, 0, holds in the pit as well."""
    from warp_terrain.inference.selfcheck import LARGE_REFUTED, large_weight

    maps, fill, _, hidden = _pit_check(dig_hidden=True)
    assert hidden >= LARGE_REFUTED
    torch.testing.assert_close(maps[0.3], fill)
    torch.testing.assert_close(maps[None], fill)
    # fewer than LARGE_REFUTED such cells cannot measure it: all of it is kept
    cells = (torch.arange(25) < LARGE_REFUTED - 1).view(1, 1, 5, 5)
    zero = torch.zeros(1, 1, 5, 5)
    assert float(large_weight(zero - 0.5, zero, zero, cells)) == 1.0
    cells = (torch.arange(25) < LARGE_REFUTED).view(1, 1, 5, 5)
    assert float(large_weight(zero - 0.5, zero, zero, cells)) == 0.0
    assert float(large_weight(zero - 0.5, zero, zero - 0.25, cells)) == 0.5
