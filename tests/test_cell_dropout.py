"""``train.cell_dropout``: single holes in the training scans, as the self-check makes them."""

from __future__ import annotations

import pytest
import torch
from conftest import TINY_RUN, run_config

from warp_terrain.data.cell_dropout import drop_observed_cells


def scans(batch: int = 6, size: int = 40):
    g = torch.Generator().manual_seed(1)
    mask = (torch.rand(batch, 1, size, size, generator=g) < 0.4).float()
    return torch.randn(batch, 1, size, size, generator=g) * mask + 3.0 * mask, mask


def test_only_observed_cells_are_hidden_each_map_at_its_own_rate_within_the_share():
    scan, mask = scans()
    out, kept = drop_observed_cells(scan, mask, 0.3, seed=5)
    assert bool((kept <= mask).all())  # no unobserved cell becomes observed
    assert torch.equal(out, scan * kept) and torch.equal(out[kept > 0], scan[kept > 0])  # heights kept exactly, hidden ones 0
    hidden = 1.0 - kept.sum(dim=(1, 2, 3)) / mask.sum(dim=(1, 2, 3))
    assert bool((hidden <= 0.3 + 0.05).all()) and hidden.max() > 0.05  # each map's rate drawn in [0, 0.3]
    assert len(set(hidden.round(decimals=2).tolist())) > 1  # not one rate for the batch
    again = drop_observed_cells(scan, mask, 0.3, seed=5)
    assert torch.equal(again[1], kept) and not torch.equal(drop_observed_cells(scan, mask, 0.3, seed=6)[1], kept)
    assert drop_observed_cells(scan, mask, 0.0, seed=5) == (scan, mask)
    for bad in (1.0, -0.1, True, "0.2"):
        with pytest.raises(ValueError, match="share="):
            drop_observed_cells(scan, mask, bad, seed=0)


def test_a_training_step_thins_its_input_by_the_step_and_the_validation_set_is_not_thinned(tmp_path, monkeypatch):
    """The scan the model is given at step ``s`` is the stream's with the cells of
    ``drop_observed_cells(..., seed=CELL_DROPOUT_SEED + seed * 1_000_003 + s)`` hidden (so a
    resumed run thins as the first would have); with ``cell_dropout=0`` it is the stream's."""
    from warp_terrain.data.stream import training_batches
    from warp_terrain.training import session

    given = []
    for share in (0.5, 0.0):
        cfg = run_config(*TINY_RUN, "model.dropout=0.0", "model.in_channels=2", f"train.cell_dropout={share}")
        run = session.setup(cfg, tmp_path / f"run{share}")
        monkeypatch.setattr(run.model, "set_input", lambda condition, target, weight: given.append(condition.clone()))
        monkeypatch.setattr(run.model, "optimize_parameters", lambda: None)
        stream = next(training_batches(cfg.sim(), cfg.train.batch_size, cfg.train.seed, 0, 3, 4, "cpu", 0))  # step 3
        session.step(run, iter([dict(stream)]), 3)
        run.writer.close()
        scan, mask = stream["scan"], stream["mask"]
        if share:
            expected = drop_observed_cells(scan, mask, share, seed=session.CELL_DROPOUT_SEED + cfg.train.seed * 1_000_003 + 3)
            assert torch.equal(given[-1][:, :1], expected[0]) and torch.equal(given[-1][:, 1:2], expected[1])
            assert expected[1].sum() < mask.sum()
            assert torch.equal(run.val["mask"], session.validation_set(cfg.sim(), cfg.train.val_size, "cpu")["mask"])
        else:
            assert torch.equal(given[-1][:, :1], scan) and torch.equal(given[-1][:, 1:2], mask)


def test_the_dropout_finetune_recipe_is_the_first_cycle_from_its_weights_with_holes():
    from warp_terrain.compose import compose_run

    tuned = compose_run(["experiment=dropout_finetune"], files=False)
    cycle1 = compose_run(["experiment=pretrained_cycle1"], files=False)
    assert tuned.train.cell_dropout == 0.3 and cycle1.train.cell_dropout == 0.0
    assert tuned.train.init_from == "pretrained" and tuned.train.steps == 3000 and tuned.model.lr_g == 1e-4
    assert tuned.terrain == cycle1.terrain and tuned.data == cycle1.data and tuned.scans == cycle1.scans
    tuned.model.lr_g = cycle1.model.lr_g
    assert tuned.model == cycle1.model
