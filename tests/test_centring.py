"""Cell centring: each cell's returns' mean offset from its centre (``cell_offsets``), the
heights moved to the centres by the thin plate's gradient (``centre_cells``), and the
``Reconstructor`` option that does it for a cloud."""

import numpy as np
import pytest
import torch

import warp_terrain as wt
from warp_terrain.cli import build_parser
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.models import ModelConfig, build_generator
from warp_terrain.models.centring import centre_cells
from warp_terrain.sim.projection import cell_offsets

S, CELL = 21, 0.25
EXACT = (400,) * 5  # CG steps per level: the thin plate solved to float32's precision
CENTRES = (torch.arange(S, dtype=torch.float64) - (S - 1) / 2) * CELL


def test_offsets_are_each_cells_points_mean_offset_from_its_centre():
    points = np.array([
        [0.10, -0.05, 1.0], [-0.06, 0.05, 7.0],    # cell (10, 10): mean offset (0.02, 0.0)
        [0.25 + 0.12, -0.5 - 0.11, 0.0],           # cell (11, 8): (0.12, -0.11)
        [np.nan, 0.0, 0.0], [9.0, 0.0, 0.0],       # ignored: NaN, outside the map
    ], np.float32)
    offset = cell_offsets(points, map_size=S, map_cell=CELL, device="cpu")
    expected = torch.zeros(1, 2, S, S)
    expected[0, :, 10, 10] = torch.tensor([0.02, 0.0])
    expected[0, :, 11, 8] = torch.tensor([0.12, -0.11])
    torch.testing.assert_close(offset, expected, rtol=0, atol=1e-6)
    # batched, and no points at all
    both = cell_offsets(np.stack([points, points[::-1].copy()]), map_size=S, map_cell=CELL, device="cpu")
    torch.testing.assert_close(both, expected.expand(2, -1, -1, -1), rtol=0, atol=1e-6)
    assert torch.equal(cell_offsets(np.zeros((0, 3)), map_size=S, device="cpu"), torch.zeros(1, 2, S, S))


def test_offsets_refuse_what_the_projection_refuses():
    with pytest.raises(ValueError, match="points"):
        cell_offsets(np.zeros((4, 2)), map_size=S, device="cpu")
    with pytest.raises(ValueError, match="map_cell"):
        cell_offsets(np.zeros((4, 3)), map_size=S, map_cell=0.0, device="cpu")


def _plane(gx: float, gy: float, offset: torch.Tensor | None = None) -> torch.Tensor:
    """(1, 1, S, S) float64 heights of the plane 0.7 + gx x + gy y at the cell centres, moved by ``offset``."""
    x, y = CENTRES[:, None], CENTRES[None, :]
    if offset is not None:
        x, y = x + offset[0, 0].double(), y + offset[0, 1].double()
    return (0.7 + gx * x + gy * y)[None, None]


def _mask(seed: int = 0, share: float = 0.3, framed: bool = True) -> torch.Tensor:
    """A random share of the cells observed and (``framed``) the map's two outer rows and
    columns: the thin plate's Laplacian is the grid's with replicated edges, which bends a
    plane next to an unobserved border; framed, every free cell lies where a plane is exact."""
    g = torch.Generator().manual_seed(seed)
    mask = (torch.rand(1, 1, S, S, generator=g) < share).float()
    if framed:
        mask[..., :2, :] = mask[..., -2:, :] = mask[..., :, :2] = mask[..., :, -2:] = 1.0
    return mask


def test_a_plane_seen_off_centre_alike_everywhere_comes_back_at_the_centres():
    """The same offset in every cell: the mean heights are the plane moved, a plane again,
    which the thin plate reproduces, so its gradient is the plane's and one solve is exact."""
    mask = _mask()
    offset = torch.tensor([0.08, -0.05]).view(1, 2, 1, 1).expand(1, 2, S, S) * mask
    scan = (_plane(0.3, -0.2, offset) * mask).float()
    centred = centre_cells(scan, mask, offset, CELL, steps=EXACT)
    torch.testing.assert_close(centred, (_plane(0.3, -0.2) * mask).float(), rtol=0, atol=1e-4)
    assert float((scan - _plane(0.3, -0.2) * mask).abs().max()) > 0.03  # the error it removed: 0.3 * 0.08 + 0.2 * 0.05


def test_no_offset_changes_nothing_and_holes_stay_empty():
    mask = _mask(1)
    scan = torch.randn(1, 1, S, S) * mask
    assert torch.equal(centre_cells(scan, mask, torch.zeros(1, 2, S, S), CELL), scan)
    filled = scan + (1 - mask) * 5.0  # whatever the holes hold, they come back 0
    assert torch.equal(centre_cells(filled, mask, torch.zeros(1, 2, S, S), CELL), scan)


def test_a_step_is_moved_no_more_than_max_slope_allows():
    """A plane of gradient 3 (a wall's face): the correction is that of gradient ``max_slope``
    along the same direction."""
    mask = _mask(2)
    offset = torch.tensor([0.1, 0.0]).view(1, 2, 1, 1).expand(1, 2, S, S) * mask
    scan = (_plane(3.0, 0.0, offset) * mask).float()
    for max_slope in (1.0, 0.5):
        centred = centre_cells(scan, mask, offset, CELL, max_slope=max_slope, steps=EXACT)
        torch.testing.assert_close(centred, scan - max_slope * 0.1 * mask, rtol=0, atol=1e-4)


def test_random_offsets_on_a_plane_lose_most_of_their_error():
    """Offsets drawn per cell make the mean heights a rough surface; the thin plate through them
    has the plane's gradient only on average, and each solve on the moved heights comes nearer."""
    mask = _mask(3, framed=False)
    g = torch.Generator().manual_seed(3)
    offset = (torch.rand(1, 2, S, S, generator=g) - 0.5) * CELL * mask
    truth = (_plane(0.3, -0.2) * mask).float()
    scan = (_plane(0.3, -0.2, offset) * mask).float()
    raw = float((scan - truth).abs().sum())
    errors = [float((centre_cells(scan, mask, offset, CELL, solves=n) - truth).abs().sum()) for n in (1, 2, 4)]
    assert errors[0] < 0.5 * raw and errors[2] < errors[1] < errors[0]


def test_the_averaged_gradient_is_the_grounds_not_the_noises():
    """A plane with 5 cm of noise on every observed height, seen 10 cm off-centre: the exact
    correction is 0.3 x 0.1 = 3 cm everywhere. The thin plate's gradient between noisy cells is
    the noise's; averaged over 2 m it is the plane's, to a fifth of the unaveraged error."""
    mask = _mask(5, framed=False)
    g = torch.Generator().manual_seed(5)
    offset = torch.tensor([0.1, 0.0]).view(1, 2, 1, 1).expand(1, 2, S, S) * mask
    scan = (_plane(0.3, -0.2, offset).float() + 0.05 * torch.randn(1, 1, S, S, generator=g)) * mask

    def correction_error(span: float) -> float:
        correction = (scan - centre_cells(scan, mask, offset, CELL, span=span))[mask > 0]
        return float(((correction - 0.03) ** 2).mean().sqrt())

    assert correction_error(2.0) < 0.25 * correction_error(0.0)
    assert correction_error(2.0) < 0.003


def test_bad_shapes_name_the_argument():
    scan = torch.zeros(1, 1, S, S)
    with pytest.raises(ValueError, match="offset"):
        centre_cells(scan, scan, torch.zeros(1, 1, S, S), CELL)
    with pytest.raises(ValueError, match="scan"):
        centre_cells(scan[0], scan[0], torch.zeros(1, 2, S, S), CELL)
    with pytest.raises(ValueError, match="solves"):
        centre_cells(scan, scan, torch.zeros(1, 2, S, S), CELL, solves=0)
    with pytest.raises(ValueError, match="span"):
        centre_cells(scan, scan, torch.zeros(1, 2, S, S), CELL, span=-1.0)


def _recording(tmp_path, **kwargs) -> tuple[Reconstructor, list]:
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=8, ndf=8, unet_depth=4)
    torch.manual_seed(0)
    Reconstructor(build_generator(cfg), cfg, {"centre_cells": True}, device="cpu").save(tmp_path / "rec.pt")
    rec = Reconstructor.load(tmp_path / "rec.pt", device="cpu", tta=False, **kwargs)
    seen = []

    def predict(scan, mask):
        seen.append(scan.clone())
        return scan, None

    rec.predict_maps_with_uncertainty = predict
    return rec, seen


def test_the_reconstructor_centres_a_clouds_cells_when_asked(tmp_path):
    """A tilted plane sampled 6 cm off each cell's centre: with the option (here from the file's
    meta) the model sees the plane at the centres; with it switched off, the returns' means."""
    x, y = np.meshgrid(np.arange(-20, 21) * CELL + 0.06, np.arange(-20, 21) * CELL, indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), -1.8 + 0.25 * x.ravel()], axis=1).astype(np.float32)
    at_centres = -1.8 + 0.25 * (x - 0.06)
    rec, seen = _recording(tmp_path)
    assert rec.centre_cells
    rec.reconstruct(points, map_size=41, map_cell=CELL)
    np.testing.assert_allclose(seen[-1][0, 0].numpy(), at_centres, rtol=0, atol=1e-4)
    rec, seen = _recording(tmp_path, centre_cells=False)
    rec.reconstruct(points, map_size=41, map_cell=CELL)
    np.testing.assert_allclose(seen[-1][0, 0].numpy(), at_centres + 0.25 * 0.06, rtol=0, atol=1e-5)


def test_the_shipped_file_does_not_centre_and_the_command_line_can():
    assert not Reconstructor.load(device="cpu").centre_cells
    parser = build_parser()
    assert parser.parse_args(["reconstruct", "cloud.ply"]).centre_cells is None
    assert parser.parse_args(["reconstruct", "cloud.ply", "--centre-cells"]).centre_cells is True
    assert wt.Reconstructor is Reconstructor


def test_the_stream_carries_each_cells_offset_when_asked():
    from conftest import tiny_sim

    from warp_terrain.data.stream import PairStream, make_pair, validation_set

    sim = tiny_sim()
    plain = make_pair(sim, 2, 7, "cpu")
    pair = make_pair(sim, 2, 7, "cpu", offsets=True)
    assert "offset" not in plain and torch.equal(pair["scan"], plain["scan"])
    points = wt.generate_batch(2, sim, seed=7, device="cpu").points
    assert torch.equal(pair["offset"], cell_offsets(points, sim.data.map_size, sim.data.map_cell, device="cpu"))
    assert bool((pair["offset"].abs().amax(dim=1, keepdim=True) > 0).le(pair["mask"] > 0).all())  # offsets only where returns are
    assert validation_set(sim, 2, "cpu", offsets=True)["offset"].shape == (2, 2, sim.data.map_size, sim.data.map_size)
    stream = iter(PairStream(sim, 2, 0, stop=1, offsets=True))
    assert next(stream)["offset"].shape == (2, 2, sim.data.map_size, sim.data.map_size)


def test_a_run_that_centres_refuses_pairs_without_points(tmp_path):
    from conftest import TINY_RUN, run_config

    with pytest.raises(ValueError, match="model.centre_cells=true.*train.dataset"):
        run_config(*TINY_RUN, "model.centre_cells=true", f"train.dataset={tmp_path}")
    scan = tmp_path / "a.npz"
    np.savez(scan, points=np.zeros((10, 3), np.float32))
    with pytest.raises(ValueError, match="^model.centre_cells=true: real scans mixed in"):
        run_config(*TINY_RUN, "model.gan_mode=none", "model.centre_cells=true", "scans.share=0.5", f"scans.files=[{scan}]")


def test_a_run_that_centres_trains_on_centred_cells_and_its_file_centres_clouds(tmp_path, monkeypatch):
    """Two steps through the loop: every training and validation scan it gives the model is the
    centred scan of its pair; the checkpoint's Reconstructor centres a cloud's cells by default."""
    from conftest import TINY_RUN, run_config

    import warp_terrain.training.session as session
    from warp_terrain.training import train

    calls = []

    def spying(scan, mask, offset, map_cell, **kwargs):
        out = centre_cells(scan, mask, offset, map_cell, **kwargs)
        calls.append(out)
        return out

    monkeypatch.setattr(session, "centre_cells", spying)
    cfg = run_config(*TINY_RUN, "model.centre_cells=true", "train.steps=2", "train.val_every=2", "train.image_every=2",
                     "train.checkpoint_every=2")
    out = train(cfg, tmp_path / "run")
    assert out["steps"] == 2 and np.isfinite(out["val_rmse_unobserved"])
    assert len(calls) == 3  # the validation set once, then each step's batch
    rec = Reconstructor.load(tmp_path / "run" / "checkpoints" / "latest.pt", device="cpu")
    assert rec.centre_cells and not Reconstructor.load(tmp_path / "run" / "checkpoints" / "latest.pt", centre_cells=False).centre_cells


def test_the_centred_finetune_recipe_is_the_first_cycle_from_its_weights_with_centred_cells():
    from warp_terrain.compose import compose_run

    tuned = compose_run(["experiment=centred_finetune"], files=False)
    cycle1 = compose_run(["experiment=pretrained_cycle1"], files=False)
    assert tuned.model.centre_cells and not cycle1.model.centre_cells
    assert tuned.train.init_from == "pretrained" and tuned.model.lr_g == 1e-4
    assert tuned.terrain == cycle1.terrain and tuned.data == cycle1.data and tuned.scans == cycle1.scans
    tuned.model.lr_g, tuned.model.centre_cells = cycle1.model.lr_g, False
    assert tuned.model == cycle1.model
