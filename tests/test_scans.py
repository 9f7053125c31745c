"""Real scans in the training stream (``warp_terrain.data.scans``, ``scans.*``): the hidden cells,
the turned sweep, the mixed batch and the loss weights that skip what a real pair cannot know."""

import numpy as np
import pytest
import torch
from conftest import TINY_RUN, run_config, tiny_sim
from scipy import ndimage

from warp_terrain.data.scans import ScanMixConfig, ScanPairs, hide_cells, load_scan
from warp_terrain.data.stream import PairStream
from warp_terrain.models.fill import fill_relative_weight


def _write_scan(path, points):
    np.savez(path, points=np.asarray(points, dtype=np.float32))
    return str(path)


def _ground(z=-1.7, half=4.0, step=0.05):
    """A dense flat patch of returns: every cell within ``half`` metres observed at height z."""
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]


@pytest.mark.parametrize("sigma", [0.0, 3.0])
def test_hide_cells_hides_the_asked_share_of_observed_cells_only(sigma):
    rng = np.random.default_rng(0)
    observed = rng.random((41, 41)) < 0.6
    hidden = hide_cells(observed, 0.3, sigma, rng)
    assert hidden.sum() == round(0.3 * observed.sum())
    assert not (hidden & ~observed).any()


def test_blob_hiding_makes_contiguous_holes_scattered_hiding_does_not():
    """Share of hidden cells with a hidden 4-neighbour: about the share itself (0.3) when
    scattered, most of them when the holes are blobs 3 cells wide."""
    observed = np.ones((61, 61), dtype=bool)

    def neighbour_share(hidden):
        n = ndimage.convolve(hidden.astype(int), np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]]), mode="constant")
        return ((n > 0) & hidden).sum() / hidden.sum()

    scattered = hide_cells(observed, 0.3, 0.0, np.random.default_rng(1))
    blobs = hide_cells(observed, 0.3, 3.0, np.random.default_rng(1))
    assert neighbour_share(scattered) < 0.85  # 1 - 0.7**4 = 0.76 for independent cells
    assert neighbour_share(blobs) > 0.95


def test_a_real_pair_is_its_own_measured_heights_with_some_hidden(tmp_path):
    """A flat patch 1.7 m below the sensor: the target is -1.7 on every observed cell and the
    fill value elsewhere, valid marks the observed cells, the scan keeps all but the hidden share."""
    cfg = ScanMixConfig(files=[_write_scan(tmp_path / "a.npz", _ground())], share=1.0, hide_min=0.2, hide_max=0.3)
    pairs = ScanPairs(cfg, map_size=41, map_cell=0.25, fill=0.5)
    for seed in range(4):
        scan, mask, target, valid = pairs.pair(np.random.default_rng(seed))
        observed = valid > 0
        assert observed.sum() > 400
        np.testing.assert_allclose(target[observed], -1.7, atol=1e-6)
        assert (target[~observed] == 0.5).all()
        assert not ((mask > 0) & ~observed).any()
        share = 1.0 - mask.sum() / observed.sum()
        assert 0.2 - 1e-3 <= share <= 0.3 + 1e-3
        np.testing.assert_allclose(scan[mask > 0], -1.7, atol=1e-6)
        assert (scan[mask == 0] == 0.5).all()


def test_the_sweep_is_turned_about_the_sensor_and_shifted(tmp_path):
    """One return 3 m ahead lands 3 m from the map's centre at any yaw without a shift (12 cells
    of 0.25 m, within rounding), and within 3 +- sqrt(2) * 1 m with shifts of up to 1 m."""
    path = _write_scan(tmp_path / "one.npz", [[3.0, 0.0, -1.0]])
    centre = 20
    for shift, (lo, hi) in ((0.0, (11.3, 12.7)), (1.0, (12 - 4 * 2**0.5 - 0.8, 12 + 4 * 2**0.5 + 0.8))):
        pairs = ScanPairs(ScanMixConfig(files=[path], share=1.0, hide_min=0.01, hide_max=0.01, shift_m=shift), 41, 0.25)
        angles = []
        for seed in range(12):
            *_, valid = pairs.pair(np.random.default_rng(seed))
            (r, c), = np.argwhere(valid > 0)
            assert lo <= np.hypot(r - centre, c - centre) <= hi
            angles.append(np.arctan2(c - centre, r - centre))
        assert np.ptp(angles) > 2.0  # turned, not always ahead


def test_a_mixed_batch_is_reproducible_and_marks_what_is_known(tmp_path):
    sim = tiny_sim()
    path = _write_scan(tmp_path / "a.npz", _ground())
    scans = ScanMixConfig(files=[path], share=0.5)
    stream = PairStream(sim, 6, seed=3, scans=scans)
    a, b = next(iter(stream)), next(iter(PairStream(sim, 6, seed=3, scans=scans)))
    for key in ("scan", "mask", "target", "valid"):
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
    real = (a["valid"] < 1).flatten(1).any(1)
    assert 0 < int(real.sum()) < 6  # seed 3 mixes some real pairs in (binomial(6, 0.5))
    # real pairs come first, synthetic ones are untouched and known everywhere
    n = int(real.sum())
    assert real[:n].all() and not real[n:].any()
    plain = next(iter(PairStream(sim, 6, seed=3)))
    assert "valid" not in plain
    for key in ("scan", "mask", "target"):
        torch.testing.assert_close(a[key][n:], plain[key][n:], rtol=0, atol=0)
    assert (a["target"][:n][a["valid"][:n] > 0] == pytest.approx(-1.7, abs=1e-6))


def test_fill_relative_weight_counts_only_known_unobserved_cells():
    """Map 0 is a real pair whose fill errs by 2 m off its returns (unknown: not counted) and by
    0.1 m on its hidden cells; map 1 errs by 0.4 m on every unobserved cell."""
    target = torch.zeros(2, 1, 4, 4)
    mask = torch.zeros(2, 1, 4, 4)
    mask[:, :, 0] = 1.0
    valid = torch.ones(2, 1, 4, 4)
    valid[0, :, 2:] = 0.0
    base = torch.zeros(2, 1, 4, 4)
    base[0, :, 1] = 0.1
    base[0, :, 2:] = 2.0
    base[1, :, 1:] = 0.4
    w = fill_relative_weight(base, target, mask, floor=0.01, valid=valid).flatten()
    inverse = torch.tensor([1 / 0.1, 1 / 0.4])
    torch.testing.assert_close(w, inverse / inverse.mean(), rtol=1e-6, atol=0)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["scans.share=0.3"], "scans.files=[]"),
        (["scans.share=1.5"], "scans.share=1.5"),
        (["scans.hide_min=0.5", "scans.hide_max=0.2"], "scans.hide_max=0.2"),
        (["scans.files=[no/such/scan.npz]"], "scans.files='no/such/scan.npz'"),
    ],
)
def test_bad_scan_mix_values_fail_naming_the_key(overrides, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        run_config(*TINY_RUN, *overrides)


def test_a_scan_mix_needs_a_loss_that_skips_unknown_cells(tmp_path):
    path = _write_scan(tmp_path / "a.npz", _ground())
    with pytest.raises(ValueError, match="model.gan_mode=none"):
        run_config(*TINY_RUN, "model.gan_mode=vanilla", "scans.share=0.5", f"scans.files=[{path}]")


def test_training_on_a_scan_mix_runs_end_to_end(tmp_path):
    """Two steps with every pair real (through the loop, its stream and its loss weights): the run
    finishes and validates (on synthetic pairs) to a finite error."""
    from warp_terrain.training import train

    path = _write_scan(tmp_path / "a.npz", _ground())
    cfg = run_config(*TINY_RUN, "model.gan_mode=none", "train.steps=2", "train.val_every=2", "train.image_every=2",
                     "train.checkpoint_every=2", "scans.share=1.0", f"scans.files=[{path}]")
    out = train(cfg, tmp_path / "run")
    assert out["steps"] == 2 and np.isfinite(out["val_rmse_unobserved"])


def test_the_scan_finetune_recipe_is_the_first_cycle_from_its_weights_with_real_scans():
    from warp_terrain.compose import compose_run

    tuned = compose_run(["experiment=scan_finetune"], files=False)
    cycle1 = compose_run(["experiment=pretrained_cycle1"], files=False)
    assert tuned.train.init_from == "pretrained" and tuned.train.steps == 3000 and tuned.model.lr_g == 1e-4
    assert tuned.scans.share == 0.25 and len(tuned.scans.files) == 7
    assert all(name.startswith("real_data/train_") for name in tuned.scans.files)  # never the suite's scans
    assert tuned.terrain == cycle1.terrain and tuned.data == cycle1.data
    tuned.model.lr_g = cycle1.model.lr_g
    assert tuned.model == cycle1.model


def test_a_scan_file_without_points_is_refused_before_any_work(tmp_path):
    """``load_scan`` (the training sweeps and the real suite): an empty or malformed ``points``
    array, or none, is named with the file."""
    _write_scan(tmp_path / "empty.npz", np.zeros((0, 3)))
    _write_scan(tmp_path / "flat.npz", np.zeros((5, 2)))
    np.savez(tmp_path / "other.npz", xyz=np.zeros((5, 3)))
    for name, message in (("empty", "N >= 1"), ("flat", "points must be"), ("other", "no 'points' array")):
        with pytest.raises(ValueError, match=message) as err:
            load_scan(tmp_path / f"{name}.npz")
        assert f"{name}.npz" in str(err.value)
