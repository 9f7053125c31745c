"""Models: shapes, Table 2 fidelity, losses, one-batch training, checkpoints, config checks."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch
from torch import nn

from warp_terrain.models import (
    GANLoss,
    ModelConfig,
    PaperUNet,
    PatchDiscriminator,
    Pix2PixModel,
    UNet,
    build_generator,
    build_model,
)

SIZE = 121


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


def _batch(b=2, in_channels=1, size=SIZE):
    """A smooth target in metres and a sparse, masked condition derived from it."""
    g = torch.Generator().manual_seed(1)
    target = torch.randn(b, 1, size, size, generator=g).cumsum(-1).cumsum(-2) / size
    mask = (torch.rand(b, 1, size, size, generator=g) < 0.4).float()
    condition = torch.cat([target * mask, mask][:in_channels], dim=1)
    return condition, target


# -- PaperUNet: Table 2 ------------------------------------------------------------------

TABLE2_ENCODER = [(64, 3, 2, "valid"), (128, 4, 2, "same"), (256, 4, 2, "valid"),
                  (512, 4, 2, "same"), (512, 4, 2, "same"), (512, 4, 2, "same")]
TABLE2_DECODER = [(512, 4, 2, "same"), (512, 4, 2, "same"), (512, 4, 1, "valid"),
                  (512, 4, 2, "same"), (256, 4, 2, "valid"), (128, 4, 2, "same")]


def test_paper_unet_matches_table2():
    net = PaperUNet()  # ngf 64: Table 2's filter counts
    stages = ((net.encoder, TABLE2_ENCODER, nn.Conv2d), (net.decoder, TABLE2_DECODER, nn.ConvTranspose2d))
    for blocks, table, kind in stages:
        got = []
        for block in blocks:
            conv = block.conv
            assert isinstance(conv, kind)
            assert conv.kernel_size[0] == conv.kernel_size[1] and conv.stride[0] == conv.stride[1]
            got.append((conv.out_channels, conv.kernel_size[0], conv.stride[0], conv.tf_padding))
        assert got == table
    assert isinstance(net.encoder[0].norm, nn.Identity)  # no norm on the first conv
    assert all(isinstance(b.norm, nn.BatchNorm2d) for b in list(net.encoder[1:]) + list(net.decoder))
    assert all(isinstance(b.act, nn.LeakyReLU) and b.act.negative_slope == 0.2 for b in net.encoder)
    assert all(isinstance(b.act, nn.ReLU) for b in net.decoder)
    assert [isinstance(b.dropout, nn.Dropout) for b in net.decoder] == [True] * 3 + [False] * 3
    assert net.final.out_channels == 1


def test_paper_unet_sizes_and_shape():
    net = PaperUNet(ngf=8)
    sizes = []
    for block in list(net.encoder) + list(net.decoder) + [net.final]:
        block.register_forward_hook(lambda m, i, o: sizes.append((i[0].shape[-1], o.shape[-1])))
    out = net(torch.randn(2, 1, SIZE, SIZE))
    assert out.shape == (2, 1, SIZE, SIZE)
    # The size table of paper_unet's docstring (decoder inputs after crop/pad alignment).
    assert sizes == [(121, 60), (60, 30), (30, 14), (14, 7), (7, 4), (4, 2),
                     (2, 4), (4, 8), (7, 10), (14, 28), (30, 62), (60, 120), (120, 121)]


def test_paper_unet_tf_same_padding_is_asymmetric():
    from warp_terrain.models.paper_unet import TFConv2d

    conv = TFConv2d(1, 1, 4, 2, "same", bias=False)
    nn.init.ones_(conv.weight)
    y = conv(torch.ones(1, 1, 7, 7))  # TF: pad 1 before, 2 after -> 4x4
    assert y.shape == (1, 1, 4, 4)
    assert y[0, 0, 0, 0] == 9 and y[0, 0, -1, -1] == 4 and y[0, 0, 1, 1] == 16


def test_paper_unet_no_output_bound():
    net = PaperUNet(ngf=8).eval()
    with torch.no_grad():
        net.final.bias.fill_(-5.0)  # heights in metres: nothing squashes to [-1, 1]
        assert net(torch.zeros(1, 1, SIZE, SIZE)).mean() < -4


# -- UNet, PatchGAN, GANLoss ---------------------------------------------------------------


@pytest.mark.parametrize("in_channels", [1, 2])
def test_unet_keeps_size(in_channels):
    net = UNet(in_channels=in_channels, out_channels=1, ngf=8, depth=7)
    assert net(torch.randn(2, in_channels, SIZE, SIZE)).shape == (2, 1, SIZE, SIZE)
    assert UNet(in_channels, ngf=4, depth=3)(torch.randn(1, in_channels, 50, 37)).shape == (1, 1, 50, 37)


def test_patchgan_logit_map():
    net = PatchDiscriminator(in_channels=2, out_channels=1, ndf=8, n_layers=3)
    out = net(torch.randn(3, 3, SIZE, SIZE))
    assert out.dim() == 4 and out.shape[:2] == (3, 1) and out.shape[2] > 1 and out.shape[3] > 1
    assert out.shape[2:] == (13, 13)
    assert not isinstance(net.model[-1], nn.Sigmoid)


def test_gan_loss_modes():
    x = torch.tensor([[-2.0, 0.0], [0.5, 3.0]]).view(1, 1, 2, 2)
    vanilla, lsgan = GANLoss("vanilla"), GANLoss("lsgan")
    bce, mse = nn.BCEWithLogitsLoss(), nn.MSELoss()
    ones, zeros = torch.ones_like(x), torch.zeros_like(x)
    assert torch.allclose(vanilla(x, True), bce(x, ones))
    assert torch.allclose(vanilla(x, False), bce(x, zeros))
    assert torch.allclose(lsgan(x, True), mse(x, ones))
    assert torch.allclose(lsgan(x, False), mse(x, zeros))
    assert torch.allclose(lsgan(x, False), (x**2).mean())
    assert torch.allclose(GANLoss()(x, True), bce(x, ones))  # the default is the paper's (vanilla) loss
    with pytest.raises(ValueError, match="gan_mode"):
        GANLoss("wgan")


def test_build_generator_selects_by_name():
    assert isinstance(build_generator(ModelConfig(name="paper", ngf=4)), PaperUNet)
    assert isinstance(build_generator({"name": "unet", "ngf": 4}), UNet)


# -- Pix2PixModel ----------------------------------------------------------------------------


@pytest.mark.parametrize("name,in_channels", [("paper", 1), ("unet", 2)])
def test_pix2pix_steps_reduce_l1(name, in_channels):
    model = build_model(ModelConfig(name=name, in_channels=in_channels, ngf=8, ndf=8))
    condition, target = _batch(b=2, in_channels=in_channels)
    model.set_input(condition, target)
    l1 = []
    for _ in range(20):
        losses = model.optimize_parameters()
        assert set(losses) == {"discriminator", "generator_gan", "l1"}
        assert all(isinstance(v, torch.Tensor) and not v.requires_grad for v in losses.values())
        values = model.loss_values()
        assert all(isinstance(v, float) and v == v for v in values.values())
        l1.append(values["l1"])
    first, last = sum(l1[:4]) / 4, sum(l1[-4:]) / 4
    assert last < 0.95 * first, l1  # seed 0: ~0.6 (paper), ~0.85 (unet)
    visuals = model.get_current_visuals()
    assert set(visuals) == {"condition", "prediction", "target"}
    assert visuals["prediction"].shape == target.shape and not visuals["prediction"].requires_grad


def _gan_loss_by_hand(logits: torch.Tensor, real: bool, gan_mode: str) -> torch.Tensor:
    """lsgan: mean (x - label)^2; vanilla: binary cross-entropy of the logits, mean log(1 + e^-x)
    against "real" and mean log(1 + e^x) against "fake"."""
    if gan_mode == "lsgan":
        return (logits - (1.0 if real else 0.0)).square().mean()
    return torch.nn.functional.softplus(-logits if real else logits).mean()


@pytest.mark.parametrize("norm,gan_mode", [("instance", "lsgan"), ("none", "vanilla"), ("batch", "lsgan")])
def test_pix2pix_norm_and_gan_variants(norm, gan_mode):
    """Both nets carry the configured norm layers (and no other kind), and one step reports the
    losses of the configured objective, computed here by hand from copies of the nets taken
    before the step: D's 0.5 (L(D(fake), fake) + L(D(real), real)) with D as it was, G's
    adversarial L(D'(fake), real) with D' the discriminator after its step, and the L1 of the
    prediction. Same float32 operations: measured equal to ~1e-7, tolerance rtol 1e-5."""
    norm_kinds = {"batch": nn.BatchNorm2d, "instance": nn.InstanceNorm2d}
    for name in ("paper", "unet"):
        cfg = ModelConfig(name=name, ngf=4, ndf=4, unet_depth=3, norm=norm, gan_mode=gan_mode, dropout=0.0)
        model = build_model(cfg)
        for net in (model.netG, model.netD):
            kinds = {kind for kind in norm_kinds.values() if any(isinstance(m, kind) for m in net.modules())}
            assert kinds == ({norm_kinds[norm]} if norm in norm_kinds else set()), (name, type(net).__name__)
        condition, target = _batch(b=1, size=SIZE if name == "paper" else 32)
        generator, discriminator = copy.deepcopy(model.netG), copy.deepcopy(model.netD)
        model.set_input(condition, target)
        values = model.optimize_parameters()
        with torch.no_grad():
            fake = generator(condition)
            fake_pair, real_pair = torch.cat([condition, fake], 1), torch.cat([condition, target], 1)
            d_loss = 0.5 * (_gan_loss_by_hand(discriminator(fake_pair), False, gan_mode)
                            + _gan_loss_by_hand(discriminator(real_pair), True, gan_mode))
            expected = {"discriminator": d_loss, "generator_gan": _gan_loss_by_hand(model.netD(fake_pair), True, gan_mode),
                        "l1": (fake - target).abs().mean()}
        assert set(values) == set(expected)
        for key, value in expected.items():
            torch.testing.assert_close(values[key], value, rtol=1e-5, atol=1e-7, msg=f"{name} {key}")


def test_pix2pix_weighted_l1():
    model = build_model(ModelConfig(name="unet", ngf=4, ndf=4, unet_depth=3))
    prediction, target = torch.zeros(1, 1, 4, 4), torch.ones(1, 1, 4, 4)
    weight = torch.zeros(1, 1, 4, 4)
    weight[..., :2, :] = 2.0
    assert model.l1_loss(prediction, target).item() == pytest.approx(1.0)
    assert model.l1_loss(prediction, target, weight).item() == pytest.approx(1.0)
    assert model.l1_loss(prediction, target, torch.ones_like(weight)).item() == pytest.approx(1.0)
    weight[..., :2, :] = 1.0
    assert model.l1_loss(prediction, target, weight).item() == pytest.approx(0.5)
    condition, target = _batch(b=1, size=32)
    model.set_input(condition, target, weight=torch.ones(1, 1, 32, 32))
    model.optimize_parameters()
    with pytest.raises(ValueError, match="weight"):
        model.set_input(condition, target, weight=torch.ones(1, 2, 32, 32))
    with pytest.raises(ValueError, match="condition"):
        model.set_input(torch.cat([condition, condition], 1), target)


def test_the_squared_height_loss_is_the_weighted_mean_squared_error_of_the_step():
    """``height_loss="l2"``: the height term is mean(weight * error^2), by hand on errors of 0, 1
    and 3 m; and the loss a step reports is that of the generator before the step, weighted."""
    model = build_model(ModelConfig(name="unet", ngf=4, ndf=4, unet_depth=3, gan_mode="none", height_loss="l2"))
    prediction, target = torch.zeros(1, 1, 2, 2), torch.tensor([[[[0.0, 1.0], [3.0, -3.0]]]])
    weight = torch.tensor([[[[1.0, 2.0], [0.5, 0.0]]]])
    assert model.l1_loss(prediction, target, power=2).item() == pytest.approx((0 + 1 + 9 + 9) / 4)
    assert model.l1_loss(prediction, target, weight, power=2).item() == pytest.approx((0 + 2 + 4.5 + 0) / 4)
    condition, target = _batch(b=2, size=32)
    weight = torch.rand(2, 1, 32, 32, generator=torch.Generator().manual_seed(0))
    generator = copy.deepcopy(model.netG)
    model.set_input(condition, target, weight)
    values = model.optimize_parameters()
    with torch.no_grad():
        expected = (weight * (generator(condition) - target).square()).mean()
    torch.testing.assert_close(values["l1"], expected, rtol=1e-5, atol=0)
    with pytest.raises(ValueError, match="height_loss"):
        ModelConfig(height_loss="huber").validate()


def test_pix2pix_state_dict_round_trip(tmp_path):
    cfg = ModelConfig(name="paper", ngf=4, ndf=4)
    condition, target = _batch(b=2)
    model = build_model(cfg)
    model.set_input(condition, target)
    for _ in range(2):
        model.optimize_parameters()
    path = tmp_path / "model.pt"
    torch.save(model.state_dict(), path)
    state = torch.load(path, weights_only=True)

    torch.manual_seed(123)  # different initial weights
    restored = build_model(cfg)
    restored.load_state_dict(state)
    assert not torch.equal(build_model(cfg).predict(condition), model.predict(condition))
    assert torch.equal(restored.predict(condition), model.predict(condition))
    assert Pix2PixModel.from_state_dict(state).cfg == cfg

    # Optimiser state restored too: one more identical step keeps them identical.
    for m in (model, restored):
        torch.manual_seed(7)  # same dropout masks
        m.set_input(condition, target)
        m.optimize_parameters()
    assert torch.equal(restored.predict(condition), model.predict(condition))


def test_pix2pix_modes_and_predict():
    model = build_model(ModelConfig(name="unet", ngf=4, ndf=4, unet_depth=3))
    assert model.training
    condition, _ = _batch(b=1, size=16)
    out = model.predict(condition)
    assert model.training and not out.requires_grad  # predict restores the mode
    assert torch.equal(out, model.predict(condition))  # eval: no dropout
    model.eval()
    assert not model.netG.training and not model.netD.training
    model.train()
    assert model.netG.training and model.netD.training
    assert model.to("cpu") is model and model.device == torch.device("cpu")


# -- ModelConfig.validate --------------------------------------------------------------------

BAD_FIELDS = [
    ("name", "resnet"), ("norm", "group"), ("gan_mode", "wgan"),
    ("in_channels", 0), ("out_channels", -1), ("ngf", 0), ("ndf", 0), ("disc_layers", 0),
    ("unet_depth", 1), ("lr_g", 0.0), ("lr_d", -1e-4), ("lambda_l1", -1.0),
    ("dropout", 1.0), ("dropout", -0.1), ("beta1", 1.0), ("beta2", -0.5), ("beta2", 1.5),
]


def test_config_defaults_are_the_papers():
    cfg = ModelConfig().validate()
    assert (cfg.lambda_l1, cfg.lr_g, cfg.lr_d, cfg.beta1, cfg.gan_mode) == (100.0, 2e-4, 2e-4, 0.5, "vanilla")


@pytest.mark.parametrize("field,value", BAD_FIELDS)
def test_config_rejects_bad_field(field, value):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(ModelConfig(), **{field: value}).validate()


def test_config_coerce():
    assert ModelConfig.coerce({"ngf": 8}) == ModelConfig(ngf=8)
    with pytest.raises(ValueError, match="ngff"):
        ModelConfig.coerce({"ngff": 8})
