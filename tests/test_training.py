"""Training: Hydra composition, the stream, the loop, TensorBoard, checkpoints and resume."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import ROOT, TINY_RUN, run_config
from hydra import compose, initialize_config_module

from warp_terrain.compose import CONFIG_MODULE, compose_run, register_configs
from warp_terrain.core.torchfile import load_checkpoint
from warp_terrain.data.seeds import VALIDATION_SEED_BASE, batch_seed
from warp_terrain.data.stream import training_batches, validation_set
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.plots.callbacks import PaperFigures
from warp_terrain.training import RunConfig, train

TINY = TINY_RUN


def test_default_composition_is_typed_and_valid():
    cfg = run_config()
    assert cfg.terrain.name == "octave5" and cfg.lidar.name == "hdl32e"
    assert cfg.model.name == "unet" and cfg.model.residual and cfg.model.in_channels == 2  # model=fill_residual
    assert cfg.data.map_size == 121


@pytest.mark.parametrize("name", ["paper_octave3_noise05", "paper_octave3_noise10", "paper_octave5_noise05", "paper_octave5_noise10"])
def test_paper_experiments_reproduce_the_paper_settings(name):
    cfg = run_config(f"experiment={name}")
    octaves, noise = int(name[12]), int(name[-2:]) / 100
    assert cfg.terrain.octaves == octaves and cfg.data.noise == pytest.approx(noise)
    assert cfg.model.ngf == 64 and cfg.model.lambda_l1 == 100 and cfg.model.lr_g == cfg.model.lr_d == 2e-4
    assert cfg.model.beta1 == 0.5 and cfg.train.batch_size == 1 and cfg.train.steps == 60_000


@pytest.mark.parametrize("preset", ["vlp16", "hdl32e", "hdl64e", "os1-64", "os1-128"])
def test_lidar_group_selects_the_published_presets(preset):
    from warp_terrain import lidar_preset

    assert run_config(f"lidar={preset}").lidar == lidar_preset(preset)


@pytest.mark.parametrize(
    "override, message",
    [
        ("terrain.octaves=-1", "terrain.octaves"),
        ("data.noise=2.0", "data.noise"),
        ("train.steps=0", "train.steps"),
        ("model.lr_g=-1", "model.lr_g"),
        ("lidar.elevations_deg=[]", "lidar.elevations_deg"),
        ("model=paper data.map_size=64", "data.map_size"),  # the paper net is for 121x121
        ("model.residual=true model.in_channels=1", "model.residual"),
    ],
)
def test_bad_values_fail_naming_the_key(override, message):
    with pytest.raises(ValueError, match=message):
        run_config(*override.split())


def test_wrong_type_or_unknown_key_fails_at_composition():
    from hydra.errors import ConfigCompositionException
    from omegaconf.errors import ValidationError

    with pytest.raises((ValidationError, ConfigCompositionException)):
        run_config("terrain.octaves=many")
    with pytest.raises(ConfigCompositionException):
        run_config("terrain.octavez=3")


def test_stream_seeds_are_reproducible_disjoint_and_ordered():
    assert batch_seed(0, 0, 5) == batch_seed(0, 0, 5)
    seeds = {batch_seed(0, r, s) for r in range(2) for s in range(500)}
    assert len(seeds) == 1000 and max(seeds) < VALIDATION_SEED_BASE
    cfg = run_config(*TINY)
    sim = cfg.sim()
    a = training_batches(sim, 2, seed=0, rank=0, start=3, stop=6, device="cpu", workers=0)
    b = training_batches(sim, 2, seed=0, rank=0, start=0, stop=6, device="cpu", workers=0)
    later = [next(b) for _ in range(6)][3:]
    for x, y in zip(a, later):
        assert int(x["step"]) == int(y["step"]) and torch.equal(x["scan"], y["scan"])
    other_rank = next(training_batches(sim, 2, seed=0, rank=1, start=3, stop=4, device="cpu", workers=0))
    assert not torch.equal(other_rank["target"], later[0]["target"])


@pytest.mark.slow
def test_worker_processes_give_the_same_stream_in_order():
    cfg = run_config(*TINY)
    sim = cfg.sim()
    inline = list(training_batches(sim, 2, seed=1, rank=0, start=0, stop=4, device="cpu", workers=0))
    spawned = list(training_batches(sim, 2, seed=1, rank=0, start=0, stop=4, device="cpu", workers=2, prefetch=1))
    assert [int(x["step"]) for x in spawned] == [0, 1, 2, 3]
    for x, y in zip(inline, spawned):
        assert torch.equal(x["scan"], y["scan"]) and torch.equal(x["target"], y["target"])


def _events(run_dir: Path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(run_dir / "tensorboard"), size_guidance={"scalars": 0, "images": 0})
    ea.Reload()
    return ea


@pytest.mark.slow
def test_training_logs_checkpoints_and_resumes_exactly(tmp_path):
    # constant learning rates: a longer run would otherwise decay them on another schedule
    steps = ["train.val_every=2", "train.image_every=2", "train.checkpoint_every=2", "train.lr_decay_from=1.0"]
    cfg = run_config(*TINY, *steps, "train.steps=4")
    first = train(cfg, tmp_path / "run", callbacks=[PaperFigures()])
    assert Path(first["checkpoint"]).is_file() and Path(first["images"]).stat().st_size > 0
    ea = _events(tmp_path / "run")
    tags = ea.Tags()
    for tag in ("loss/discriminator", "loss/generator_gan", "loss/l1", "val/rmse_unobserved", "throughput/data_wait_share", "lr/generator"):
        assert tag in tags["scalars"], tag
    assert [e.step for e in ea.Scalars("loss/l1")] == [1, 2, 3, 4]
    assert tags["images"], "no image grid logged"
    assert {"figures/fig5_reconstruction_3d", "figures/fig6_input_prediction_truth"} <= set(tags["images"])
    state = load_checkpoint(first["checkpoint"])  # weights_only=True inside
    assert state["step"] == 4

    # continue the same run folder to 6 steps, and compare with an uninterrupted 6-step run
    resumed = train(run_config(*TINY, *steps, "train.steps=6", "train.resume=true"), tmp_path / "run")
    straight = train(run_config(*TINY, *steps, "train.steps=6"), tmp_path / "straight")
    a, b = load_checkpoint(resumed["checkpoint"]), load_checkpoint(straight["checkpoint"])
    assert a["step"] == b["step"] == 6
    for name, tensor in a["model"]["netG"].items():
        torch.testing.assert_close(tensor, b["model"]["netG"][name], rtol=1e-4, atol=1e-5, msg=name)
    assert [e.step for e in _events(tmp_path / "run").Scalars("loss/l1")][-2:] == [5, 6]


def test_the_scaled_residual_model_with_uncertainty_trains_and_logs_its_calibration(tmp_path):
    """Two steps, validated at step 2: the logged scores are those of the saved model on the
    validation pairs, recomputed here through the Reconstructor (sigma = sqrt(exp(log-variance)))
    on the unobserved cells only: the RMSE, the shares of errors within 1 and 2 sigma, and the
    RMS sigma. TensorBoard keeps float32 and the two paths batch the maps differently: shares to
    one cell in their count, the others to rtol 1e-5."""
    cfg = run_config(*TINY, "model.in_channels=2", "model.residual=true", "model.height_scale_min=0.05",
                     "model.uncertainty=true", "train.steps=2", "train.val_every=2")
    summary = train(cfg, tmp_path / "run")
    ea = _events(tmp_path / "run")
    assert [e.step for e in ea.Scalars("loss/nll")] == [1, 2]
    logged = {}
    for key in ("rmse_unobserved", "uncertainty_within_1sigma_unobserved", "uncertainty_within_2sigma_unobserved",
                "uncertainty_rms_sigma_unobserved"):
        (event,) = ea.Scalars(f"val/{key}")
        assert event.step == 2, key
        logged[key] = event.value

    rec = Reconstructor.load(summary["checkpoint"], device="cpu", tta=False)
    assert rec.has_uncertainty and rec.sigma_scale == 1.0
    val = validation_set(cfg.sim(), cfg.train.val_size, "cpu")
    height, sigma = rec.predict_maps_with_uncertainty(val["scan"], val["mask"])
    unobserved = val["mask"] == 0
    error = (height - val["target"]).double()[unobserved].abs()
    sigma = sigma.double()[unobserved]
    cells = int(unobserved.sum())
    assert 0 < cells < unobserved.numel()
    assert logged["rmse_unobserved"] == pytest.approx(float(error.square().mean().sqrt()), rel=1e-5)
    assert summary["val_rmse_unobserved"] == pytest.approx(logged["rmse_unobserved"], rel=1e-6)
    assert logged["uncertainty_within_1sigma_unobserved"] == pytest.approx(float((error <= sigma).double().mean()), abs=1.01 / cells)
    assert logged["uncertainty_within_2sigma_unobserved"] == pytest.approx(float((error <= 2 * sigma).double().mean()), abs=1.01 / cells)
    assert logged["uncertainty_rms_sigma_unobserved"] == pytest.approx(float(sigma.square().mean().sqrt()), rel=1e-5)


@pytest.mark.slow
def test_same_seed_and_config_train_bit_identically_on_cpu(tmp_path, monkeypatch):
    """Two fresh runs with one seed: the same batches, so bit-identical losses and weights;
    another seed draws other batches and ends elsewhere."""
    steps = ["train.steps=3", "train.val_every=3", "train.image_every=3", "train.checkpoint_every=3", "train.threads=1"]
    runs = {name: train(run_config(*TINY, *steps, f"train.seed={seed}"), tmp_path / name)
            for name, seed in (("a", 7), ("b", 7), ("c", 8))}
    weights = {name: load_checkpoint(run["checkpoint"])["model"]["netG"] for name, run in runs.items()}
    losses = {name: [e.value for e in _events(tmp_path / name).Scalars("loss/l1")] for name in runs}
    assert losses["a"] == losses["b"] and len(losses["a"]) == 3
    assert all(torch.equal(t, weights["b"][k]) for k, t in weights["a"].items())
    assert losses["a"] != losses["c"]
    assert not all(torch.equal(t, weights["c"][k]) for k, t in weights["a"].items())


def test_init_from_starts_the_generator_from_a_model_file_and_refuses_another_net(tmp_path):
    """``train.init_from``: the run's generator starts with the file's weights exactly (fp16
    weights read back as float), the optimisers afresh; a file whose net differs is refused
    naming each differing field, before the run folder exists; a resumed run keeps its own."""
    from warp_terrain.models import build_generator
    from warp_terrain.training.session import setup

    cfg = run_config(*TINY, "model.dropout=0.0")
    source = Reconstructor(build_generator(cfg.model), cfg.model, device="cpu")
    for p in source.generator.parameters():  # weights a fresh run would never draw
        p.data.uniform_(-0.5, 0.5)
    source.save(tmp_path / "source.pt")
    expected = Reconstructor.load(tmp_path / "source.pt", device="cpu").generator.state_dict()
    run = setup(run_config(*TINY, "model.dropout=0.0", f"train.init_from={tmp_path / 'source.pt'}"), tmp_path / "run")
    got = run.model.generator.state_dict()
    assert set(got) == set(expected) and all(torch.equal(got[k], expected[k]) for k in expected)
    assert not run.model.optimizer_G.state  # no moments carried over
    run.writer.close()

    with pytest.raises(ValueError, match=r"train.init_from=.*model.ngf=8 \(the run: 16\).*model.dropout=0.0 \(the run: 0.5\)"):
        setup(run_config(*TINY, "model.ngf=16", f"train.init_from={tmp_path / 'source.pt'}"), tmp_path / "other")
    assert not (tmp_path / "other").exists()
    with pytest.raises(ValueError, match="train.init_from"):
        run_config(*TINY, f"train.init_from={tmp_path / 'missing.pt'}")
    # a recorded recipe read where its files are absent: composed as written, not looked for
    assert compose_run([*TINY, f"train.init_from={tmp_path / 'missing.pt'}"], files=False).train.init_from == str(tmp_path / "missing.pt")

    # a run that adds the screened fill as an input starts from the file's net widened by a zero column
    residual = ["model=fill_residual", *TINY[1:], "model.dropout=0.0", "model.refine=1"]
    narrow = run_config(*residual).model
    Reconstructor(build_generator(narrow), narrow, device="cpu").save(tmp_path / "narrow.pt")
    expected = Reconstructor.load(tmp_path / "narrow.pt", device="cpu").generator.state_dict()
    wide = setup(run_config(*residual, "model.screened_input=0.1", f"train.init_from={tmp_path / 'narrow.pt'}"), tmp_path / "wide")
    got = wide.model.generator.state_dict()
    widened = [k for k in expected if got[k].shape != expected[k].shape]  # the U-Net's first convolution, the head's
    assert len(widened) == 2 and all(torch.equal(got[k][:, :-1], expected[k]) and not got[k][:, -1].any() for k in widened)
    assert all(torch.equal(got[k], expected[k]) for k in expected if k not in widened)
    wide.writer.close()
    # the noise-widened bound of observed cells holds no weight: a run may add it to the file's net
    clipped = run_config(*residual, "model.observed_bound=0.1").model
    Reconstructor(build_generator(clipped), clipped, device="cpu").save(tmp_path / "clipped.pt")
    expected = Reconstructor.load(tmp_path / "clipped.pt", device="cpu").generator.state_dict()
    bounded = setup(run_config(*residual, "model.observed_bound=0.1", "model.observed_bound_noise=3",
                               f"train.init_from={tmp_path / 'clipped.pt'}"), tmp_path / "bounded")
    got = bounded.model.generator.state_dict()
    assert all(torch.equal(got[k], expected[k]) for k in expected) and bounded.model.generator.noise_bound == 3.0
    bounded.writer.close()
    with pytest.raises(ValueError, match=r"model.observed_bound=0.1 \(the run: 0.2\)"):  # the bound itself is the net's
        setup(run_config(*residual, "model.observed_bound=0.2", f"train.init_from={tmp_path / 'clipped.pt'}"), tmp_path / "b2")

    steps = ["train.steps=1", "train.val_every=1", "train.checkpoint_every=1", "train.image_every=1", "model.dropout=0.0"]
    first = train(run_config(*TINY, *steps), tmp_path / "resumed")
    resumed = setup(run_config(*TINY, *steps, "train.resume=true", f"train.init_from={tmp_path / 'source.pt'}"), tmp_path / "resumed")
    weights = load_checkpoint(first["checkpoint"])["model"]["netG"]
    assert all(torch.equal(resumed.model.generator.state_dict()[k], v) for k, v in weights.items())
    resumed.writer.close()


def test_resume_from_a_missing_checkpoint_fails_clearly(tmp_path):
    with pytest.raises(ValueError, match="no checkpoint"):
        train(run_config(*TINY, "train.steps=2", "train.resume=true"), tmp_path / "empty")


def _train_py(*args, cwd):
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_train_py_bad_override_fails_fast_with_a_clear_message(tmp_path):
    bad = _train_py("terrain.octaves=-1", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert bad.returncode != 0 and "terrain.octaves=-1" in bad.stderr and "Traceback" not in bad.stderr
    assert not (tmp_path / "run").exists()  # a refused run leaves no folder
    nope = _train_py("model=nope", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert nope.returncode != 0 and "nope" in nope.stderr


@pytest.mark.slow
def test_train_py_multirun_sweep_completes(tmp_path):
    out = _train_py(
        "-m",
        *TINY,
        "train.steps=2",
        "train.val_every=2",
        "terrain=octave3,octave5",
        "data.noise=0.05,0.10",
        f"hydra.sweep.dir={tmp_path}/sweep",
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    summaries = sorted((tmp_path / "sweep").glob("*/summary.json"))
    assert len(summaries) == 4
    for path in summaries:
        assert json.loads(path.read_text())["steps"] == 2


@pytest.mark.slow
def test_torchrun_ddp_two_gloo_ranks_train_on_different_data(tmp_path):
    run_dir = tmp_path / "ddp"
    out = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(ROOT / "train.py"),
         *TINY, "train.steps=3", "train.val_every=3", f"hydra.run.dir={run_dir}"],
        cwd=tmp_path, capture_output=True, text=True, timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    main = json.loads((run_dir / "summary.json").read_text())
    other = json.loads((run_dir / "summary_rank1.json").read_text())
    assert main["world_size"] == 2 and main["steps"] == 3
    assert set(main["first_batch_seeds"]).isdisjoint(other["first_batch_seeds"])  # ranks see different data
    assert load_checkpoint(main["checkpoint"])["step"] == 3


def test_slurm_launcher_config_composes():
    register_configs()
    with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
        cfg = compose(config_name="config", overrides=["hydra/launcher=slurm_gpu"], return_hydra_config=True)
    assert cfg.hydra.launcher._target_.endswith("SlurmLauncher")
    assert cfg.hydra.launcher.gpus_per_node == 1


@pytest.mark.slow
def test_sweep_through_the_submitit_local_launcher(tmp_path):
    out = _train_py("-m", "hydra/launcher=submitit_local", *TINY, "train.steps=2", "train.val_every=2",
                    "terrain=octave3,octave5", f"hydra.sweep.dir={tmp_path}/sweep", "hydra.launcher.timeout_min=5", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert len(list((tmp_path / "sweep").glob("*/summary.json"))) == 2


class _Payload:
    """Unpickling this would create a file: a stand-in for code planted in a checkpoint."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.mark.parametrize("loader", ["checkpoint", "reconstructor"])
def test_a_planted_pickle_payload_never_runs(tmp_path, loader):

    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pt"
    torch.save({"model": _Payload(marker), "step": 1}, path)
    with pytest.raises(ValueError, match="evil.pt"):
        load_checkpoint(path) if loader == "checkpoint" else Reconstructor.load(path)
    assert not marker.exists()


def test_the_shipped_model_was_trained_with_experiment_pretrained():
    """The run config recorded beside the shipped model is what `python train.py
    experiment=pretrained` composes (only the progress bar, the resume flag, the torch threads and
    the path to the second cycle's weights may differ), and the shipped weights are that model's
    net (averaged with the second cycle's, the same net; warp_terrain/pretrained/README.md)."""
    from omegaconf import OmegaConf

    from warp_terrain.inference.reconstructor import pretrained_path

    recorded = OmegaConf.to_container(OmegaConf.load(pretrained_path().parent / "run_config.yaml"))

    # the recipe names real_data/'s Finland raster, which a clean checkout has not fetched
    composed = OmegaConf.to_container(OmegaConf.structured(compose_run(["experiment=pretrained"], files=False)))
    defaults = OmegaConf.to_container(OmegaConf.structured(RunConfig()))
    for cfg in (recorded, composed):
        # how the run was driven on its machine (progress bar, resumes, torch threads), not the recipe
        for key in ("progress", "resume", "threads"):
            cfg["train"].pop(key)
    # where the second cycle's weights were read from: the recipe names its run folder, the shipped
    # run the folder the second cycle ran in
    assert composed["train"].pop("init_from") == "outputs/pretrained_cycle2/checkpoints/latest.pt"
    assert recorded["train"].pop("init_from") == "outputs/second16k/checkpoints/latest.pt"

    def newer_keys_at_their_defaults(recorded, composed, defaults, where=""):
        """Keys the schema gained after the model was trained must sit at their defaults
        (groups added later are off by default); every recorded key must be as recorded."""
        for key, value in composed.items():
            if key not in recorded:
                assert value == defaults[key], f"{where}{key}: not in the recorded config and not at its default"
                recorded[key] = value
            elif isinstance(value, dict):
                newer_keys_at_their_defaults(recorded[key], value, defaults[key], f"{where}{key}.")

    newer_keys_at_their_defaults(recorded, composed, defaults)
    assert recorded == composed
    rec = Reconstructor.load(device="cpu")
    # fields that hold no weight are the packaging's (warp_terrain/pretrained/README.md), not the recipe's
    from warp_terrain.models.config import UNWEIGHTED_FIELDS

    packaged = {k: v for k, v in rec.model_config.to_dict().items() if k not in UNWEIGHTED_FIELDS}
    assert packaged == {k: v for k, v in composed["model"].items() if k not in UNWEIGHTED_FIELDS}
    assert rec.meta["step"] == composed["train"]["steps"]


def test_the_shipped_recipe_is_its_cycles_in_turn():
    """Each cycle of the recipe is the one before it run again from its weights, with batches no
    earlier cycle drew; the third also reaches higher mounts, and nothing else differs."""
    cycle1, cycle2, shipped = (compose_run([f"experiment={name}"], files=False)
                               for name in ("pretrained_cycle1", "pretrained_cycle2", "pretrained"))
    assert (cycle1.train.init_from, cycle1.train.seed) == ("", 0)
    assert (cycle2.train.init_from, cycle2.train.seed) == ("outputs/pretrained_cycle1/checkpoints/latest.pt", 1)
    assert (shipped.train.init_from, shipped.train.seed) == ("outputs/pretrained_cycle2/checkpoints/latest.pt", 2)
    assert cycle1.data.randomize.mount_height_max == cycle2.data.randomize.mount_height_max == 2.5
    assert shipped.data.randomize.mount_height_max == 3.5
    shipped.data.randomize.mount_height_max = 2.5
    for cfg in (cycle1, cycle2, shipped):
        cfg.train.init_from, cfg.train.seed = "", 0
    assert cycle1 == cycle2 == shipped
