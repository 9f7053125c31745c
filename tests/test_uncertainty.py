"""The per-map height scaling of the residual generator and the uncertainty (log-variance) head."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import warp_terrain as wt
from warp_terrain.evaluation import evaluate, format_table
from warp_terrain.evaluation.metrics import calibration
from warp_terrain.inference.onnx import check_onnx, export_onnx
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.models import ModelConfig, build_generator, build_model
from warp_terrain.models.fill import loss_weight_map, observed_spread, push_pull_fill
from warp_terrain.models.uncertainty import LOG_VARIANCE_RANGE, gaussian_nll, split_output

SCALED = ModelConfig(name="unet", in_channels=2, residual=True, ngf=8, ndf=8, unet_depth=4, height_scale_min=0.05, uncertainty=True)


def _maps(seed=0, batch=2, size=33):
    g = torch.Generator().manual_seed(seed)
    scan = torch.randn(batch, 1, size, size, generator=g)
    mask = (torch.rand(batch, 1, size, size, generator=g) < 0.3).float()
    return scan * mask, mask


def test_observed_spread_is_the_standard_deviation_of_the_observed_heights():
    scan = torch.zeros(2, 1, 4, 4)
    mask = torch.zeros(2, 1, 4, 4)
    scan[0, 0, 0, :2] = torch.tensor([1.0, 3.0])  # observed: 1 and 3 -> mean 2, std 1
    mask[0, 0, 0, :2] = 1.0
    reference = torch.tensor([2.0, 0.0]).view(2, 1, 1, 1)
    spread = observed_spread(scan, mask, reference, floor=0.05)
    assert spread[0].item() == pytest.approx(1.0)
    assert spread[1].item() == pytest.approx(0.05)  # no observed cell: the floor
    assert observed_spread(scan, mask, reference, floor=2.5)[0].item() == pytest.approx(2.5)


def test_loss_weights_per_cell_and_per_relief():
    scan = torch.zeros(2, 1, 2, 2)
    mask = torch.tensor([[1.0, 1.0], [0.0, 0.0]]).expand(2, 1, 2, 2).clone()
    scan[0, 0, 0] = torch.tensor([-1.0, 1.0])  # spread 1 m
    scan[1, 0, 0] = torch.tensor([-0.25, 0.25])  # spread 0.25 m
    assert loss_weight_map(scan, mask) is None
    cells = loss_weight_map(scan, mask, unobserved_weight=3.0)
    torch.testing.assert_close(cells[0, 0], torch.tensor([[0.5, 0.5], [1.5, 1.5]]))  # 1 : 3, mean 1
    relief = loss_weight_map(scan, mask, relief_floor=0.05)
    torch.testing.assert_close(relief[:, 0, 0, 0], torch.tensor([0.4, 1.6]))  # 1/1 : 1/0.25, batch mean 1
    both = loss_weight_map(scan, mask, unobserved_weight=3.0, relief_floor=0.05)
    torch.testing.assert_close(both, cells * relief)
    floored = loss_weight_map(scan, mask, relief_floor=0.5)  # spreads 1 and max(0.25, 0.5)
    torch.testing.assert_close(floored[:, 0, 0, 0], torch.tensor([2 / 3, 4 / 3]))


def test_scaled_residual_generator_is_equivariant_to_the_relief():
    """Heights a*z + c give a*height + c and sigma * |a| (a > 0, spreads above the floor)."""
    torch.manual_seed(0)
    g = build_generator(SCALED).eval()
    scan, mask = _maps()
    a, c = 3.0, -1.7
    with torch.no_grad():
        h1, v1 = split_output(g(torch.cat([scan, mask], 1)), True)
        h2, v2 = split_output(g(torch.cat([(a * scan + c) * mask, mask], 1)), True)
    torch.testing.assert_close(h2, a * h1 + c, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(v2, v1 + 2 * math.log(a), atol=1e-4, rtol=1e-4)


def test_scaled_residual_with_a_zero_correction_is_the_fill():
    torch.manual_seed(0)
    g = build_generator(SCALED).eval()
    last = [m for m in g.modules() if isinstance(m, torch.nn.ConvTranspose2d)][-1]
    torch.nn.init.zeros_(last.weight)
    torch.nn.init.zeros_(last.bias)
    scan, mask = _maps()
    with torch.no_grad():
        height, log_variance = split_output(g(torch.cat([scan, mask], 1)), True)
    torch.testing.assert_close(height, push_pull_fill(scan, mask))
    reference = (scan * mask).sum((2, 3), keepdim=True) / mask.sum((2, 3), keepdim=True)
    expected = 2 * torch.log(observed_spread(scan, mask, reference, 0.05)).expand_as(log_variance)
    torch.testing.assert_close(log_variance, expected)


def test_the_log_variance_nll_is_minimal_at_the_squared_error_and_leaves_the_height_alone():
    error = torch.tensor([0.1, 0.5, 2.0], requires_grad=True)
    log_variance = torch.log(error.detach() ** 2).requires_grad_(True)
    gaussian_nll(log_variance, error).backward()
    torch.testing.assert_close(log_variance.grad, torch.zeros(3), atol=1e-7, rtol=0)  # d/ds 0.5(e^2 e^-s + s) = 0 at s = log e^2
    assert error.grad is None  # the error is detached: the NLL does not move the height
    out = torch.full((1, 2, 2, 2), 100.0)
    assert split_output(out, True)[1].max().item() == LOG_VARIANCE_RANGE[1]
    assert split_output(out, False)[1] is None and split_output(out, False)[0].shape == (1, 1, 2, 2)


def test_pix2pix_with_uncertainty_learns_the_error_scale():
    """Steps on a fixed batch: the NLL falls and the predicted sigma comes to match the real
    error of the training-mode prediction (it starts at the relief's spread, about 15x the error);
    `predict` still returns one height channel."""
    torch.manual_seed(0)
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=8, ndf=8, unet_depth=4, height_scale_min=0.05,
                      uncertainty=True, gan_mode="none", lr_g=2e-3)
    model = build_model(cfg)
    b = wt.generate_batch(4, seed=1)
    condition = torch.cat([b.scan, b.mask], 1)
    model.set_input(condition, b.target)
    first = model.optimize_parameters()
    assert set(first) == {"discriminator", "generator_gan", "l1", "nll"}
    assert (model.log_variance.exp().mean().sqrt() / (model.prediction - b.target).square().mean().sqrt()).item() > 2.0
    for _ in range(120):
        last = model.optimize_parameters()
    assert last["nll"] < first["nll"] - 1.0
    rmse = (model.prediction - b.target).square().mean().sqrt()
    rms_sigma = model.log_variance.exp().mean().sqrt()
    assert 0.6 < (rms_sigma / rmse).item() < 1.6, (rms_sigma.item(), rmse.item())
    height, log_variance = model.predict_with_uncertainty(condition)
    assert model.predict(condition).shape == height.shape == log_variance.shape == (4, 1, 121, 121)


def test_calibration_known_answers():
    target = torch.zeros(1, 1, 2, 2)
    prediction = torch.tensor([0.5, -1.5, 3.0, 10.0]).view(1, 1, 2, 2)
    sigma = torch.ones(1, 1, 2, 2)
    cells = torch.tensor([True, True, True, False]).view(1, 1, 2, 2)
    fit = calibration(prediction, sigma, target, cells)
    assert fit["within_1sigma"] == pytest.approx(1 / 3)
    assert fit["within_2sigma"] == pytest.approx(2 / 3)
    assert fit["rms_sigma"] == pytest.approx(1.0)
    assert math.isnan(calibration(prediction, sigma, target, torch.zeros_like(cells))["within_1sigma"])


def test_evaluate_scores_the_calibration_of_a_predictor_that_gives_sigma():
    def with_sigma(scan, mask):
        return scan, torch.full_like(scan, 0.25)

    results = evaluate({"scan": lambda s, m: s, "sigma": with_sigma}, settings="octave3", noise=[0.0], size=2, device="cpu")
    metrics = results["settings"][0]["metrics"]
    assert "within_1sigma" not in metrics["scan"]
    assert metrics["sigma"]["rms_sigma"] == pytest.approx(0.25)
    assert metrics["sigma"]["rmse_unobserved"] == metrics["scan"]["rmse_unobserved"]
    assert "unobs within 2 sigma" in format_table(results)


def test_reconstructor_writes_the_uncertainty_and_onnx_exports_it(tmp_path):
    from warp_terrain.cli import main

    torch.manual_seed(0)
    rec = Reconstructor(build_generator(SCALED), SCALED, {}, device="cpu")
    model = tmp_path / "rec.pt"
    rec.save(model)
    rec = Reconstructor.load(model, device="cpu")
    assert rec.has_uncertainty
    b = wt.generate_batch(1, seed=2)
    points = b.points[0].numpy()
    points = points[~np.isnan(points[:, 0])]
    maps = rec.reconstruct_all(points)
    assert set(maps) == {"height", "mask", "uncertainty"}
    assert maps["uncertainty"].shape == (121, 121) and (maps["uncertainty"] > 0).all()
    np.testing.assert_array_equal(maps["height"], rec.reconstruct(points))

    cloud, out = tmp_path / "cloud.npy", tmp_path / "map.npz"
    np.save(cloud, points)
    assert main(["reconstruct", str(cloud), "--out", str(out), "--model", str(model)]) == 0
    with np.load(out) as f:
        np.testing.assert_allclose(f["uncertainty"], maps["uncertainty"], rtol=1e-5)

    path = export_onnx(rec.generator, tmp_path / "g.onnx", 2, uncertainty=True)
    report = check_onnx(rec.generator, path, torch.cat([b.scan, b.mask], 1), repeats=1, uncertainty=True)
    assert report["outputs"] == ["height", "log_variance"] and report["max_abs_diff"] < 1e-4


class _ScanWithConstantSigma(torch.nn.Module):
    """height = the scan itself; log-variance 2 log 0.2 everywhere (sigma 0.2 m)."""

    def forward(self, condition):
        scan = condition[:, :1]
        return torch.cat([scan, torch.full_like(scan, 2 * math.log(0.2))], dim=1)


def test_sigma_scale_is_the_rms_error_over_sigma_on_validation_pairs():
    from warp_terrain.data.stream import make_pair, validation_seed
    from warp_terrain.evaluation.calibrate import CALIBRATION_FIRST_CHUNK, fit_sigma_scale
    from warp_terrain.sim import SimConfig

    cfg = ModelConfig(name="unet", in_channels=2, uncertainty=True)
    rec = Reconstructor(_ScanWithConstantSigma(), cfg, {"sigma_scale": 7.0}, device="cpu", tta=False)
    k = fit_sigma_scale(rec, SimConfig(), size=20)
    errors = []
    for i, n in ((0, 16), (1, 4)):
        pair = make_pair(SimConfig(), n, validation_seed(CALIBRATION_FIRST_CHUNK + i), "cpu")
        errors.append((pair["scan"] - pair["target"])[pair["mask"] <= 0].double())
    rmse = torch.cat(errors).square().mean().sqrt().item()
    assert k == pytest.approx(rmse / 0.2, rel=1e-6)
    assert rec.meta["sigma_scale"] == 7.0  # the stored factor is left as it was
    rec.meta["sigma_scale"] = k
    assert rec.predict_maps_with_uncertainty(*_maps(size=9))[1].flatten()[0].item() == pytest.approx(0.2 * k)
    with pytest.raises(ValueError, match="no uncertainty head"):
        fit_sigma_scale(Reconstructor(_ScanWithConstantSigma(), ModelConfig(in_channels=2), device="cpu"), SimConfig())


def test_package_model_keeps_the_generator_and_calibrates_its_uncertainty(tmp_path, capsys):
    import json

    from omegaconf import OmegaConf

    from warp_terrain.cli import main
    from warp_terrain.compose import RunConfig

    torch.manual_seed(0)
    model = build_model(SCALED)
    run = OmegaConf.to_container(OmegaConf.structured(RunConfig(model=SCALED)))
    checkpoint, out = tmp_path / "latest.pt", tmp_path / "model.pt"
    torch.save({"model": model.state_dict(), "step": 3, "config": run}, checkpoint)
    assert main(["package-model", str(checkpoint), "--out", str(out), "--calibrate", "16", "--device", "cpu"]) == 0
    report = json.loads(capsys.readouterr().out)
    rec = Reconstructor.load(out, device="cpu")
    assert report["step"] == rec.meta["step"] == 3 and report["sigma_scale"] == pytest.approx(rec.sigma_scale) and rec.sigma_scale > 0
    assert out.stat().st_size < checkpoint.stat().st_size / 2  # the generator alone, in fp16
    assert main(["package-model", str(checkpoint), "--out", str(tmp_path / "raw.pt"), "--calibrate", "0"]) == 0
    assert Reconstructor.load(tmp_path / "raw.pt", device="cpu").sigma_scale == 1.0
    assert report["sigma_scale_unresolved"] is None and "sigma_scale_unresolved" not in rec.meta  # not checked: no fallback
    # a checked sigma: the fallback of the maps the check cannot resolve is fitted too, on the same
    # pairs (noisy ones here, whose errors the check cannot see under the noise)
    run["data"]["noise"] = 0.3
    torch.save({"model": model.state_dict(), "step": 3, "config": run}, checkpoint)
    checked = tmp_path / "checked.pt"
    capsys.readouterr()
    assert main(["package-model", str(checkpoint), "--out", str(checked), "--calibrate", "16", "--device", "cpu",
                 "--self-check", "--check-reach", "--check-sigma"]) == 0
    report = json.loads(capsys.readouterr().out)
    rec = Reconstructor.load(checked, device="cpu")
    unresolved = rec.meta.get("sigma_scale_unresolved")
    assert unresolved is not None and unresolved > 0 and report["sigma_scale_unresolved"] == pytest.approx(unresolved)
    assert rec.unresolved_sigma_factor == pytest.approx(unresolved / rec.sigma_scale)
