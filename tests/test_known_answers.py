"""Known answers: exact expectations from geometry and closed forms, tight enough that a plausible
breakage of the core behaviour (a cell sampled instead of averaged, a flatter fBm, a classical
fill swapped for another, a discriminator trained the wrong way round, a misplaced USD mesh, an
ONNX graph that differs from torch) fails them. Each test states its tolerance and why.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import warp as wp
from conftest import tiny_sim

import warp_terrain as wt
from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.kernels.noise import octave_fields
from warp_terrain.models.config import ModelConfig
from warp_terrain.models.fill import push_pull_fill
from warp_terrain.models.pix2pix import Pix2PixModel, build_generator
from warp_terrain.sim.batch import terrain_size


# ------------------------------------------------------------------------------ ground truth
def _aligned_sim():
    """The tiny setting without augmentation, terrain vertices every quarter map cell: the 4 x 4
    truth samples of a map cell then sit at the centres of the 16 terrain cells it covers."""
    sim = tiny_sim()
    sim.data.augment = False
    sim.data.truth_samples = 4
    sim.terrain.cell = sim.data.map_cell / 4
    return sim


def _vertex_grid(sim):
    n = terrain_size(sim)
    x = (np.arange(n) - 0.5 * (n - 1)) * sim.terrain.cell
    return np.meshgrid(x, x, indexing="ij")


def _map_centres(sim):
    s, h = sim.data.map_size, sim.data.map_cell
    c = (np.arange(s) - 0.5 * (s - 1)) * h
    return np.meshgrid(c, c, indexing="ij")


def _world_target(batch) -> np.ndarray:
    return batch.target[0, 0].numpy().astype(np.float64) + float(batch.sensor_z[0])


def test_ground_truth_of_a_quadratic_is_the_exact_mean_of_its_triangulated_surface():
    """z = a x^2 + b y^2 + d x + e y + f on vertices t = h/4 apart (h: the map cell).

    Mean over a map cell centred at (X, Y): exactly q(X, Y) + (a + b) h^2 / 12 for the quadratic;
    the triangulated surface adds (a + b) t^2 / 6 (linear interpolation of x^2 over a terrain
    cell of width t overestimates it by t^2/6 on average; the linear terms are exact). The
    4 x 4 truth samples are the terrain cells' centres, where the triangulated surface is
    (h00 + h11) / 2 = q + (a + b) t^2 / 4 and whose 16-point mean equals that cell mean
    exactly, so the answer is exact up to float32 (measured 4e-6 m on heights up to 30 m):
    tolerance 2e-5 m. Sampling the cell centre instead is (a + b) h^2 / 12 = 6.8 mm off.
    """
    sim = _aligned_sim()
    a, b, d, e, f = 0.8, 0.5, 0.3, -0.2, 0.1
    X, Y = _vertex_grid(sim)
    heights = (a * X**2 + b * Y**2 + d * X + e * Y + f).astype(np.float32)[None]
    batch = wt.generate_batch(1, sim, seed=3, device="cpu", heights=heights)
    CX, CY = _map_centres(sim)
    h, t = sim.data.map_cell, sim.terrain.cell
    centre = a * CX**2 + b * CY**2 + d * CX + e * CY + f
    exact = centre + (a + b) * h**2 / 12 + (a + b) * t**2 / 6
    np.testing.assert_allclose(_world_target(batch), exact, rtol=0, atol=2e-5)
    assert (a + b) * h**2 / 12 > 300 * 2e-5  # the centre sample is far outside the tolerance


def test_ground_truth_of_a_cell_cut_by_an_obstacle_edge_is_the_area_weighted_mean():
    """A 1 m step (an obstacle's wall) whose one-terrain-cell ramp lies inside a map cell's
    third quarter: the cell averages 0 over two quarters, the ramp's mean 0.5 over one and 1
    over one, so (0 + 0 + 0.5 + 1) / 4 = 0.375 exactly; the cell's centre sees 0."""
    sim = _aligned_sim()
    X, _ = _vertex_grid(sim)
    s, h, t = sim.data.map_size, sim.data.map_cell, sim.terrain.cell
    p = s // 2 + 5  # a map cell east of the sensor
    left = (p - 0.5 * (s - 1) - 0.5) * h  # the cell's lower x edge
    ramp_start = left + 2 * t  # ramp from vertex at left + 2t (height 0) to left + 3t (height 1)
    heights = (X > ramp_start + 0.5 * t).astype(np.float32)[None]
    batch = wt.generate_batch(1, sim, seed=3, device="cpu", heights=heights)
    target = _world_target(batch)
    np.testing.assert_allclose(target[p], 0.375, rtol=0, atol=1e-5)
    np.testing.assert_allclose(target[p - 1], 0.0, rtol=0, atol=1e-5)
    np.testing.assert_allclose(target[p + 1], 1.0, rtol=0, atol=1e-5)


# ------------------------------------------------------------------------------ fBm
@wp.kernel
def _noise_at(fields: wp.array(dtype=wp.uint32), points: wp.array(dtype=wp.vec2), out: wp.array(dtype=float)):
    k = wp.tid()
    out[k] = wp.noise(fields[k], points[k])


def _wp_noise(field: int, points: np.ndarray) -> np.ndarray:
    n = len(points)
    out = wp.empty(n, dtype=float, device="cpu")
    fields = wp.array(np.full(n, field, dtype=np.uint32), dtype=wp.uint32, device="cpu")
    wp.launch(_noise_at, dim=n, inputs=[fields, wp.array(points.astype(np.float32), dtype=wp.vec2, device="cpu")], outputs=[out], device="cpu")
    return out.numpy().astype(np.float64)


def test_fbm_is_the_documented_octave_sum_of_warps_own_noise():
    """h = amplitude * sqrt(2) * sum_o p^o noise_o(f_o (x, y) / feature_size + offset_o) / sum_o p^o
    with f_o = lacunarity^o (kernels/noise.py), evaluated here with ``wp.noise`` itself at every
    vertex. The CPU path (gradient table, and ``wp.noise`` for the finest octave here: 1.5
    vertices per lattice cell) matches to 1e-7 m; tolerance 1e-5 m on heights of +-1.7 m, so a
    terrain 29 % flatter (no sqrt(2), or a wrong normalisation) is far outside."""
    batch, size, cell, octaves, pers, lac, fs, amp, seed = 2, 33, 0.25, 4, 0.5, 2.0, 3.0, 1.7, 11
    h = wt.fractal_heightfield(batch, size, cell, octaves=octaves, persistence=pers, lacunarity=lac, feature_size=fs,
                               amplitude=amp, seed=seed, device="cpu").numpy().astype(np.float64)
    fields = wp.empty((batch, octaves), dtype=wp.uint32, device="cpu")
    offsets = wp.empty((batch, octaves), dtype=wp.vec2, device="cpu")
    wp.launch(octave_fields, dim=(batch, octaves), inputs=[wp.full(1, seed, dtype=int, device="cpu"), 0], outputs=[fields, offsets], device="cpu")
    F, O = fields.numpy(), offsets.numpy()
    u = (np.arange(size) - 0.5 * (size - 1)) * cell / fs
    U, V = np.meshgrid(u, u, indexing="ij")
    for b in range(batch):
        total, weights = np.zeros(U.size), 0.0
        for o in range(octaves):
            points = np.stack([U.ravel(), V.ravel()], axis=1) * lac**o + O[b, o]
            total += pers**o * _wp_noise(int(F[b, o]), points)
            weights += pers**o
        expected = (amp * np.sqrt(2.0) * total / weights).reshape(size, size)
        np.testing.assert_allclose(h[b], expected, rtol=0, atol=1e-5)
        assert np.abs(h[b]).max() <= amp
    assert np.abs(h).max() > 0.5 * amp  # not a degenerate, flat field


# ------------------------------------------------------------------------------ classical fills
S = 41
_I, _J = np.indices((S, S), dtype=np.float64)
PLANE = 0.04 * _I - 0.03 * _J + 1.2
SADDLE = PLANE + 0.002 * ((_I - 20) ** 2 - (_J - 20) ** 2)  # harmonic, so biharmonic too


def _hole_mask() -> np.ndarray:
    """Everything observed but a 17 x 22 hole (the classic inpainting setting)."""
    known = np.ones((S, S), dtype=bool)
    known[12:29, 8:30] = False
    return known


def _sparse_mask() -> np.ndarray:
    """A quarter of the cells at random plus the map's border (so the convex hull is the map)."""
    known = np.random.default_rng(5).random((S, S)) < 0.25
    known[[0, -1], :] = True
    known[:, [0, -1]] = True
    return known


def _fill(name: str, z: np.ndarray, known: np.ndarray) -> np.ndarray:
    scan = torch.tensor(np.where(known, z, 0.0), dtype=torch.float32)[None, None]
    mask = torch.tensor(known, dtype=torch.float32)[None, None]
    out = BASELINES[name](scan, mask)[0, 0].numpy().astype(np.float64)
    np.testing.assert_array_equal(out[known], z[known].astype(np.float32))  # observed cells are kept
    return out


def _unobserved_error(name: str, z: np.ndarray, known: np.ndarray) -> float:
    return float(np.abs(_fill(name, z, known) - z)[~known].max())


@pytest.mark.parametrize("mask", [_hole_mask, _sparse_mask], ids=["hole", "sparse"])
@pytest.mark.parametrize("name", ["linear", "plane"])
def test_linear_and_plane_fills_reproduce_a_plane(name, mask):
    """Both are exact on a plane (up to float32: measured 2e-7 m): tolerance 1e-5 m, where the
    nearest fill errs by 0.14 m or more."""
    known = mask()
    assert _unobserved_error(name, PLANE, known) < 1e-5
    assert _unobserved_error("nearest", PLANE, known) > 0.1


@pytest.mark.parametrize("z", [PLANE, SADDLE], ids=["plane", "plane+x2-y2"])
def test_biharmonic_fill_reproduces_a_biharmonic_field_in_a_hole(z):
    """A plane plus x^2 - y^2 solves the biharmonic equation, so skimage's inpainting of a hole
    gives it back (measured 5e-8 m): tolerance 1e-5 m. Nearest errs by > 0.1 m on both."""
    known = _hole_mask()
    assert _unobserved_error("biharmonic", z, known) < 1e-5
    assert _unobserved_error("nearest", z, known) > 0.1


@pytest.mark.parametrize("mask", [_hole_mask, _sparse_mask], ids=["hole", "sparse"])
@pytest.mark.parametrize("z", [PLANE, SADDLE], ids=["plane", "plane+x2-y2"])
def test_harmonic_fill_reproduces_a_discrete_harmonic_field(z, mask):
    """A plane plus x^2 - y^2 has a zero 5-point Laplacian, so with the map's border observed
    (both masks) Laplace interpolation gives it back exactly, in a hole and between scattered
    cells alike (a direct sparse solve; measured 1e-7 m): tolerance 1e-5 m."""
    known = mask()
    assert _unobserved_error("harmonic", z, known) < 1e-5
    assert _unobserved_error("nearest", z, known) > 0.05


def test_harmonic_fill_is_the_mean_of_its_neighbours_with_reflecting_edges():
    """The defining property on a free border: every unobserved cell, edge and corner cells
    included, is the mean of its grid neighbours (those inside the map)."""
    rng = np.random.default_rng(8)
    z = rng.normal(0.0, 1.0, (S, S))
    known = rng.random((S, S)) < 0.2
    out = _fill("harmonic", z, known)
    pad = np.pad(out, 1, constant_values=np.nan)
    neighbours = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    mean = np.nanmean(neighbours, axis=0)
    np.testing.assert_allclose(out[~known], mean[~known], rtol=0, atol=1e-5)
    assert np.abs(out[~known] - _fill("nearest", z, known)[~known]).max() > 0.1


def test_biharmonic_fill_beats_nearest_on_sparse_cells():
    """Scattered cells: skimage's biharmonic is not exact near its free boundary, but its RMSE on
    unobserved cells is measured at 7 % (plane) and 10 % (plane + x^2 - y^2) of nearest's; the
    test asks for less than a third."""
    known = _sparse_mask()
    for z in (PLANE, SADDLE):
        rmse = {k: float(np.sqrt(((_fill(k, z, known) - z)[~known] ** 2).mean())) for k in ("biharmonic", "nearest")}
        assert rmse["biharmonic"] < rmse["nearest"] / 3, rmse


@pytest.mark.parametrize("name", ["telea", "ns"])
def test_opencv_fills_keep_a_constant_map_constant(name):
    """OpenCV's inpainting adds up to ~1.4 m of speckle to a constant float map unless the
    heights are first scaled onto 0..65535 (baselines.py); with the scaling the documented error
    bound is ~2/65535 of the 1 m minimum span: tolerance 1e-4 m."""
    z = np.full((S, S), 1.7)
    assert _unobserved_error(name, z, _hole_mask()) < 1e-4
    assert _unobserved_error(name, z, _sparse_mask()) < 1e-4


@pytest.mark.parametrize("name", ["telea", "ns"])
def test_opencv_fills_of_a_sparse_plane_stay_in_range_and_beat_nearest(name):
    """Telea and Navier-Stokes are not exact on planes (they smooth along isophotes), but on the
    sparse plane they stay within the observed heights (1 mm slack) and their RMSE on unobserved
    cells is below nearest's (measured 0.033 and 0.036 m against 0.042 m). Without the scaling
    onto 0..65535 Telea is metres off."""
    known = _sparse_mask()
    out = _fill(name, PLANE, known)
    lo, hi = PLANE[known].min(), PLANE[known].max()
    assert lo - 1e-3 <= out.min() and out.max() <= hi + 1e-3
    rmse = {k: float(np.sqrt(((_fill(k, PLANE, known) - PLANE)[~known] ** 2).mean())) for k in (name, "nearest")}
    assert rmse[name] < rmse["nearest"], rmse


# ------------------------------------------------------------------------------ push-pull
def _plane_tensor():
    i, j = torch.meshgrid(torch.arange(S, dtype=torch.float32), torch.arange(S, dtype=torch.float32), indexing="ij")
    return (0.04 * i - 0.03 * j + 1.2)[None, None]


def test_push_pull_keeps_observed_cells_exactly_and_constants_constant():
    g = torch.Generator().manual_seed(0)
    heights = torch.randn(2, 1, S, S, generator=g)
    mask = (torch.rand(2, 1, S, S, generator=g) < 0.2).float()
    out = push_pull_fill(heights * mask, mask)
    assert torch.equal(out[mask > 0], heights[mask > 0])
    constant = torch.full_like(heights, -2.5)
    np.testing.assert_allclose(push_pull_fill(constant * mask, mask).numpy(), -2.5, rtol=0, atol=1e-5)
    assert torch.equal(push_pull_fill(heights, torch.zeros_like(mask)), torch.zeros_like(heights))


def test_push_pull_brings_back_a_sparse_plane():
    """A plane rising 4 cm and falling 3 cm per cell (2.8 m over the map), a quarter of its
    cells observed: push-pull is a smooth average, not exact on planes; measured RMSE 0.039 m
    and interior max error 0.11 m on unobserved cells. Tolerances 0.05 m and 0.15 m (a fill
    that ignored the pyramid's weights would be metres off)."""
    z = _plane_tensor()
    mask = (torch.rand(1, 1, S, S, generator=torch.Generator().manual_seed(0)) < 0.25).float()
    out = push_pull_fill(z * mask, mask)
    err = (out - z)[mask == 0]
    assert err.pow(2).mean().sqrt().item() < 0.05
    inner = (out - z)[0, 0, 4:-4, 4:-4][mask[0, 0, 4:-4, 4:-4] == 0]
    assert inner.abs().max().item() < 0.15


# ------------------------------------------------------------------------------ discriminator
@pytest.mark.slow
def test_discriminator_ranks_real_pairs_above_fakes_after_a_few_steps():
    """Eight pix2pix steps on one fixed batch: the discriminator's mean logit on each real pair
    exceeds that on the generator's fake (trained with swapped labels it would be the reverse)."""
    torch.manual_seed(0)
    batch = wt.generate_batch(4, tiny_sim(), seed=1, device="cpu")
    model = Pix2PixModel(ModelConfig(name="unet", in_channels=2, ngf=8, ndf=8, unet_depth=3))
    condition = torch.cat([batch.scan, batch.mask], dim=1)
    model.set_input(condition, batch.target)
    for _ in range(8):
        model.optimize_parameters()
    with torch.no_grad():
        fake = model.netG(condition)
        real_logit = model.netD(torch.cat([condition, batch.target], dim=1)).mean(dim=(1, 2, 3))
        fake_logit = model.netD(torch.cat([condition, fake], dim=1)).mean(dim=(1, 2, 3))
    assert real_logit.mean() > fake_logit.mean(), (real_logit, fake_logit)
    assert (real_logit > fake_logit).sum() >= 3, (real_logit, fake_logit)


# ------------------------------------------------------------------------------ USD
def test_usd_reconstruction_of_a_tilted_plane_lies_on_the_plane_with_its_normal(tmp_path):
    """Terrain z = a x + b y + c; the reconstruction is the same plane in the sensor frame on
    another grid (cell 0.25 m), minus the sensor height. Read back with pxr, each map vertex
    moved back by the Reconstruction Xform's x offset lies on the terrain's plane (1e-5 m,
    float32), and every normal is the plane's (-a, -b, 1)/|.|."""
    from pxr import Usd, UsdGeom

    a, b, c, sensor_z = 0.3, -0.2, 1.0, 1.8
    n, cell = 21, 0.5
    x = (np.arange(n) - 0.5 * (n - 1)) * cell
    X, Y = np.meshgrid(x, x, indexing="ij")
    s, rcell = 17, 0.25
    r = (np.arange(s) - 0.5 * (s - 1)) * rcell
    RX, RY = np.meshgrid(r, r, indexing="ij")
    rec = a * RX + b * RY + c - sensor_z
    path = wt.export_usd(tmp_path / "plane.usda", a * X + b * Y + c, cell, reconstruction=rec, reconstruction_cell=rcell, sensor_z=sensor_z)

    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Reconstruction/Map"))
    to_world = np.array(UsdGeom.Xformable(mesh.GetPrim()).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    local = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64)
    world = local @ to_world[:3, :3] + to_world[3, :3]  # Gf matrices act on row vectors
    offset = to_world[3, 0]
    assert offset > 0.5 * (n - 1) * cell  # beside the terrain
    np.testing.assert_allclose(world[:, 2], a * (world[:, 0] - offset) + b * world[:, 1] + c, rtol=0, atol=1e-5)
    np.testing.assert_allclose(local[:, 2], rec.reshape(-1), rtol=0, atol=1e-6)
    normal = np.array([-a, -b, 1.0]) / np.sqrt(a * a + b * b + 1.0)
    normals = np.array(mesh.GetNormalsAttr().Get(), dtype=np.float64)
    assert normals.shape == (s * s, 3)
    np.testing.assert_allclose(normals, np.broadcast_to(normal, normals.shape), rtol=0, atol=1e-5)
    terrain = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Terrain"))
    np.testing.assert_allclose(np.array(terrain.GetNormalsAttr().Get()), np.broadcast_to(normal, (n * n, 3)), rtol=0, atol=1e-5)


# ------------------------------------------------------------------------------ ONNX from the CLI
def _tiny_reconstructor(path, seed: int = 0):
    torch.manual_seed(seed)
    cfg = ModelConfig(name="unet", in_channels=2, ngf=8, ndf=8, unet_depth=3)
    generator = build_generator(cfg)
    with torch.no_grad():  # non-trivial batch-norm statistics, so a wrong export would show
        for module in generator.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    rec = wt.Reconstructor(generator, cfg, meta={}, device="cpu")
    rec.save(path)
    return wt.Reconstructor.load(path, device="cpu", tta=False)


def test_export_onnx_from_the_command_line_matches_torch(tmp_path, capsys):
    """``warp-terrain export-onnx`` on a tiny saved model: ONNX Runtime's output on fresh scans
    equals the loaded torch generator's to 1e-4 m (float32 kernels differ by ~1e-6)."""
    ort = pytest.importorskip("onnxruntime")
    from warp_terrain.cli import main

    rec = _tiny_reconstructor(tmp_path / "tiny.pt")
    out = tmp_path / "tiny.onnx"
    assert main(["export-onnx", str(out), "--model", str(tmp_path / "tiny.pt"), "--map-size", "41"]) == 0
    assert out.is_file()
    batch = wt.generate_batch(2, tiny_sim(), seed=9, device="cpu")
    condition = rec.condition(batch.scan, batch.mask)
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    (got,) = session.run(["height"], {"condition": condition.numpy()})
    with torch.no_grad():
        want = rec.generator(condition).numpy()
    assert got.shape == want.shape == (2, 1, 41, 41)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)
    assert np.abs(want).max() > 1e-3  # the comparison is not between two zero maps
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["beyond_tolerance"] == [] and set(report["max_abs_diff_by_output"]) == {"height"}


def test_export_onnx_fails_naming_the_output_beyond_its_tolerance(tmp_path, capsys, monkeypatch):
    """A difference beyond an output's tolerance exits 1 and names the output, its difference
    in its units and the tolerance (here a tolerance below any difference)."""
    pytest.importorskip("onnxruntime")
    from warp_terrain.cli import main
    from warp_terrain.inference import onnx

    _tiny_reconstructor(tmp_path / "tiny.pt")
    monkeypatch.setitem(onnx.PARITY_TOLERANCE, "height", -1.0)
    assert main(["export-onnx", str(tmp_path / "tiny.onnx"), "--model", str(tmp_path / "tiny.pt"), "--map-size", "41"]) == 1
    err = capsys.readouterr().err
    assert "error: ONNX's height differs from torch's by" in err and " m (tolerance -1)" in err
