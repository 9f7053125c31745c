"""The thin-plate base fill, the observed-cell plane and the generator built on them: known answers.

The reference is the same energy solved exactly (scipy's sparse direct solver on the assembled
matrix), so the multigrid-CG in ``models/biharmonic.py`` is checked against what it claims to
solve, and skimage's ``inpaint_biharmonic`` (the classical baseline) against what it is.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla
import torch
from skimage.restoration import inpaint_biharmonic

from warp_terrain.models.biharmonic import _eager_cg, biharmonic_fill, biharmonic_fills, conjugate_gradient, pyramid_levels, v_cycles
from warp_terrain.models.config import ModelConfig
from warp_terrain.models.fill import FillResidualGenerator, observed_plane, push_pull_fill
from warp_terrain.models.pix2pix import build_generator


def grid_laplacian(h: int, w: int) -> sp.csr_matrix:
    """G^T G of the grid graph (4-neighbour differences): minus the replicate-edge Laplacian."""
    idx = np.arange(h * w).reshape(h, w)
    rows, cols, vals = [], [], []
    for a, b in ((idx[:, :-1], idx[:, 1:]), (idx[:-1, :], idx[1:, :])):
        a, b = a.ravel(), b.ravel()
        n = np.arange(len(a)) + len(rows) // 2
        rows += [*n, *n]
        cols += [*a, *b]
        vals += [-1.0] * len(a) + [1.0] * len(a)
    g = sp.csr_matrix((vals, (rows, cols)), shape=(len(rows) // 2, h * w))
    return (g.T @ g).tocsr()


def exact_fill(z: np.ndarray, known: np.ndarray, tension: float, screening: float = 0.0) -> np.ndarray:
    n = grid_laplacian(*z.shape)
    k2 = screening**2
    plate = n @ n + 2 * k2 * n + k2 * k2 * sp.identity(n.shape[0])  # (k^2 - L)^2, L = -n
    a = ((1 - tension) * plate + tension * n).tocsr()
    k, f = known.ravel(), ~known.ravel()
    zz = np.where(known, z, 0.0).ravel().astype(np.float64)
    out = zz.copy()
    out[f] = sla.spsolve(a[f][:, f].tocsc(), -a[f][:, k] @ zz[k])
    return out.reshape(z.shape)


def rings(size: int, seed: int, share: float = 0.08) -> np.ndarray:
    """A sparse mask like a scan's: a few rings around the centre plus scattered cells."""
    rng = np.random.default_rng(seed)
    r = np.hypot(*np.mgrid[:size, :size] - (size - 1) / 2)
    mask = np.isin(np.round(r).astype(int), [3, 6, 10, 15, 22]) & (rng.random((size, size)) < 0.7)
    return mask | (rng.random((size, size)) < share)


def smooth_field(size: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:size, :size] / size
    return sum(rng.normal() * np.sin(2 * np.pi * (k * x + l * y) + rng.uniform(0, 6)) / (k + l + 1) for k in range(3) for l in range(3))


def t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float32))[None, None]


@pytest.mark.parametrize("tension", [0.0, 0.1])
def test_fill_solves_the_thin_plate_it_states(tension):
    z, known = smooth_field(48, 1), rings(48, 2)
    exact = exact_fill(z, known, tension)
    out = biharmonic_fill(t(z * known), t(known), tension=tension, steps=(128, 128, 128, 128))[0, 0].numpy()
    free = ~known
    assert np.abs(out[free] - exact[free]).max() < 4e-3 * np.abs(z).max()
    np.testing.assert_array_equal(out[known], z[known].astype(np.float32))


def wide_rings(size: int, seed: int) -> np.ndarray:
    """Three rings 9-11 cells apart, 70 % of their cells observed (8 % of the map): the wide gaps
    between a sparse 32-beam scan's rings, where the cascade stops short of the thin plate."""
    rng = np.random.default_rng(seed)
    r = np.hypot(*np.mgrid[:size, :size] - (size - 1) / 2)
    return np.isin(np.round(r).astype(int), [4, 13, 24]) & (rng.random((size, size)) < 0.7)


def energy(u: np.ndarray, tension: float) -> float:
    n = grid_laplacian(*u.shape)
    v = u.ravel().astype(np.float64)
    return float(v @ (((1 - tension) * (n @ n) + tension * n) @ v))


@pytest.mark.parametrize("tension, cycles, tolerance", [(0.0, 12, 1e-2), (0.3, 10, 1e-4)])
def test_v_cycles_finish_the_solve_the_cascade_leaves_short_in_wide_gaps(tension, cycles, tolerance):
    """The cascade's fill of wide gaps is far from the thin plate (its error more than 10 % of the
    field); V-cycles converge to the direct sparse solve of the same energy, lower the energy at
    every cycle (each coarse correction is added at its energy-minimising step) and hold the
    observed cells bit for bit."""
    z, known = smooth_field(48, 1), wide_rings(48, 2)
    exact, scale = exact_fill(z, known, tension), np.abs(z).max()
    free = ~known
    u = biharmonic_fill(t(z * known), t(known), tension=tension)
    assert np.abs(u[0, 0].numpy()[free] - exact[free]).max() > 0.1 * scale
    energies = [energy(u[0, 0].numpy(), tension)]
    for _ in range(cycles):
        u = v_cycles(u, t(known), 1, tension=tension)
        energies.append(energy(u[0, 0].numpy(), tension))
    assert np.abs(u[0, 0].numpy()[free] - exact[free]).max() < tolerance * scale
    assert all(b <= a * (1 + 1e-6) for a, b in zip(energies, energies[1:])), energies
    assert energies[-1] < (1 - 1e-3) * energies[0]
    np.testing.assert_array_equal(u[0, 0].numpy()[known], z[known].astype(np.float32))


def test_v_cycles_run_each_map_under_its_own_tension_and_name_bad_arguments():
    z, known = smooth_field(48, 1), wide_rings(48, 2)
    scan, mask = t(z * known).repeat(2, 1, 1, 1), t(known).repeat(2, 1, 1, 1)
    u = biharmonic_fill(scan, mask)
    both = v_cycles(u, mask, 2, tension=torch.tensor([0.0, 0.3]).view(2, 1, 1, 1))
    torch.testing.assert_close(both[:1], v_cycles(u[:1], mask[:1], 2), rtol=0, atol=1e-5)
    torch.testing.assert_close(both[1:], v_cycles(u[1:], mask[1:], 2, tension=0.3), rtol=0, atol=1e-5)
    assert v_cycles(u, mask, 0) is u
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="cycles must be an integer >= 0"):
            v_cycles(u, mask, bad)
    with pytest.raises(ValueError, match="tension must be in"):
        v_cycles(u, mask, 1, tension=1.5)
    with pytest.raises(ValueError, match="smoothing"):
        v_cycles(u, mask, 1, smoothing=(2, -1))


@pytest.mark.parametrize("tension", [0.0, 0.2])
def test_a_screened_fill_solves_the_matern_energy_it_states(tension):
    """``screening = k``: the thin plate's part becomes ``|L u|^2 + 2 k^2 |grad u|^2 + k^4 |u|^2``
    (precision ``(k^2 - L)^2``): the direct sparse solve of exactly that system (it converges
    fast: the screening conditions it)."""
    z, known = smooth_field(48, 5) + 2.0, rings(48, 6, share=0.03)  # it screens towards 0: an offset shows it
    exact = exact_fill(z, known, tension, screening=0.15)
    out = biharmonic_fill(t(z * known), t(known), tension=tension, steps=(256,) * 4, screening=0.15)[0, 0].numpy()
    assert np.abs(out[~known] - exact[~known]).max() < 1e-4 * np.abs(z).max()
    np.testing.assert_array_equal(out[known], z[known].astype(np.float32))
    assert np.abs(exact - exact_fill(z, known, tension)).max() > 0.02 * np.abs(z).max()  # the screening matters


def test_problems_solved_together_are_each_solved_as_alone():
    """``biharmonic_fills``: each problem's maps come back in order, each under its own tension,
    as each would alone (to float rounding: the batch only changes how sums are vectorised)."""
    z, known = smooth_field(48, 3), rings(48, 4)
    a = (t(z * known).repeat(2, 1, 1, 1), t(known).repeat(2, 1, 1, 1), 0.0)
    b = (t(2.0 * z * known), t(known), 1.0)
    c = (t(z * known) - 1.0, t(known), 0.5)
    out = biharmonic_fills([a, b, c])
    assert [o.shape[0] for o in out] == [2, 1, 1]
    for problem, got in zip((a, b, c), out):
        torch.testing.assert_close(got, biharmonic_fill(problem[0], problem[1], tension=problem[2]), rtol=0, atol=1e-5)
    assert (out[1] - 2.0 * out[0][:1]).abs().max() > 0.01  # the membrane is not the thin plate scaled
    same = biharmonic_fills([a, (t(z * known), t(known), 0.0)])  # one tension: the plain solve
    torch.testing.assert_close(same[1], biharmonic_fill(t(z * known), t(known)), rtol=0, atol=0)
    assert biharmonic_fills([]) == []


def test_a_short_step_schedule_gives_its_last_entry_to_every_finer_level():
    """``steps`` lists CG steps per level, coarsest first; levels past its end get its last entry
    and the finest level always does: ``(0, 50)`` on four levels is ``(0, 50, 50, 50)`` exactly,
    not ``(0, 0, 0, 50)``, and ``(0, 50, 50, 50, 7)`` is ``(0, 50, 50, 7)``."""
    z, known = t(smooth_field(48, 9)), t(rings(48, 10))  # 48 -> 24 -> 12 -> 6: four levels
    short = biharmonic_fill(z * known, known, steps=(0, 50))
    torch.testing.assert_close(short, biharmonic_fill(z * known, known, steps=(0, 50, 50, 50)), rtol=0, atol=0)
    assert (short - biharmonic_fill(z * known, known, steps=(0, 0, 0, 50))).abs().max() > 1e-4
    long = biharmonic_fill(z * known, known, steps=(0, 50, 50, 50, 7))
    torch.testing.assert_close(long, biharmonic_fill(z * known, known, steps=(0, 50, 50, 7)), rtol=0, atol=0)
    assert (long - short).abs().max() > 1e-4


def test_a_screened_fill_returns_to_zero_far_from_the_scan_where_the_thin_plate_runs_on():
    """Heights 1 on the first four columns only: the thin plate keeps the constant all the way
    across (a plane is reproduced), the screened fill (k = 0.2 / cell) has fallen to a few
    per cent 30 cells on and to nothing at the far edge; with no screening it is bit-identical
    to the thin plate."""
    known = np.zeros((40, 80), bool)
    known[:, :4] = True
    z = t(known.astype(float))
    plate = biharmonic_fill(z, t(known))[0, 0]
    screened = biharmonic_fill(z, t(known), screening=0.2)[0, 0]
    torch.testing.assert_close(plate, torch.ones_like(plate), rtol=0, atol=1e-4)
    assert 0.0 < screened[:, 34].max() < 0.05 and screened[:, -1].abs().max() < 1e-3
    assert (screened[:, 4:35].diff(dim=1) < 0).all()  # it falls away from the scan
    torch.testing.assert_close(biharmonic_fill(z, t(known), screening=0.0)[0, 0], plate, rtol=0, atol=0)
    for bad in (-0.1, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="screening must be a finite number >= 0"):
            biharmonic_fill(z, t(known), screening=bad)


def test_full_tension_is_the_membrane_of_the_harmonic_baseline():
    """``tension=1``: the CG pyramid solves the same Laplace interpolation as the exact sparse
    solve of ``evaluation.baselines.harmonic_fill`` (the membrane's CG converges fast: measured
    2e-4 of the field's range on rings with the default steps)."""
    from warp_terrain.evaluation.baselines import harmonic_fill

    z, known = smooth_field(48, 3), rings(48, 4)
    out = biharmonic_fill(t(z * known), t(known), tension=1.0)
    exact = harmonic_fill(t(z * known), t(known))
    torch.testing.assert_close(out, exact, rtol=0, atol=1e-3 * float(np.ptp(z)))
    np.testing.assert_array_equal(out[0, 0].numpy()[known], z[known].astype(np.float32))


def test_without_tension_it_is_skimages_biharmonic_inpainting():
    """skimage's 13-point stencil, reflected at the border, is ``(G^T G)^2``: the same surface,
    holes at the edges included."""
    z, known = smooth_field(40, 3), rings(40, 4, share=0.05)
    sk = inpaint_biharmonic(np.where(known, z, 0.0), ~known)
    agree = np.abs(exact_fill(z, known, 0.0) - sk) < 1e-6 * np.abs(z).max()
    # skimage solves each hole on its own and fills a hole cut off by the edge from its bounding
    # box; that one small hole (9 cells at the top edge here) is the only difference
    assert agree.sum() >= agree.size - 9 and agree[4:-4, 4:-4].all()


def framed(size: int, seed: int) -> np.ndarray:
    """Sparse rings inside two fully observed border rows and columns: every free cell then lies
    where the thin plate's stencil is the plain biharmonic one, whose solutions include planes."""
    known = rings(size, seed, share=0.01)
    known[:2], known[-2:], known[:, :2], known[:, -2:] = True, True, True, True
    return known


def test_a_sparse_plane_comes_back_and_the_pyramid_fill_cannot():
    r, c = np.mgrid[:121, :121].astype(np.float64)
    plane = 0.03 * r - 0.05 * c + 1.5  # 9.6 m of relief across the map
    known = framed(121, 4)
    def rms(fill):
        return float(np.sqrt(np.mean((fill(t(plane * known), t(known))[0, 0].numpy() - plane) ** 2)))

    # the exact thin plate is the plane; the default step counts stop short of it by 0.3 % of the
    # relief (rms), the pyramid average bends it seven times as much
    assert rms(biharmonic_fill) < 0.03
    assert rms(lambda z, m: biharmonic_fill(z, m, steps=(64, 64, 64, 64, 256))) < 0.015
    assert rms(push_pull_fill) > 0.2


def test_constants_stay_constant_and_an_empty_map_is_zero():
    known = t(rings(64, 5))
    np.testing.assert_allclose(biharmonic_fill(-2.5 * known, known).numpy(), -2.5, rtol=0, atol=1e-5)
    assert torch.equal(biharmonic_fill(torch.ones(1, 1, 64, 64), torch.zeros(1, 1, 64, 64)), torch.zeros(1, 1, 64, 64))


def test_fill_turns_with_the_map():
    """On a 2^k grid the pyramid is symmetric, so flips and transposes commute with the fill."""
    z, known = t(smooth_field(64, 6)), t(rings(64, 7))
    out = biharmonic_fill(z * known, known)
    for op in (lambda a: a.flip(-1), lambda a: a.flip(-2), lambda a: a.transpose(-1, -2)):
        torch.testing.assert_close(biharmonic_fill(op(z * known), op(known)), op(out), rtol=0, atol=2e-5)


def test_batched_fill_is_per_map():
    z = torch.stack([t(smooth_field(48, s))[0] for s in (8, 9)])
    known = torch.stack([t(rings(48, s))[0] for s in (10, 11)])
    both = biharmonic_fill(z * known, known)
    for i in range(2):
        torch.testing.assert_close(biharmonic_fill(z[i:i + 1] * known[i:i + 1], known[i:i + 1]), both[i:i + 1], rtol=0, atol=1e-6)


def test_pyramid_levels_and_bad_arguments():
    assert [pyramid_levels(s) for s in (8, 9, 16, 17, 121)] == [1, 2, 2, 3, 5]
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match=r"tension must be in \[0, 1\]"):
            biharmonic_fill(torch.zeros(1, 1, 8, 8), torch.ones(1, 1, 8, 8), tension=bad)
    with pytest.raises(ValueError, match="^steps must name at least one CG step count per level$"):
        biharmonic_fill(torch.zeros(1, 1, 8, 8), torch.ones(1, 1, 8, 8), steps=())


def test_per_map_tensions_take_the_maps_dtype_and_a_wrong_shape_is_named():
    """A (B, 1, 1, 1) tension tensor in float64 fills float32 maps in float32 (each map as with
    its own scalar tension); a tension tensor of the wrong shape is refused naming the shape
    the batch needs."""
    z = torch.as_tensor(np.stack([smooth_field(16, s) for s in (1, 2, 3)]), dtype=torch.float32)[:, None]
    known = torch.as_tensor(np.stack([rings(16, s) for s in (1, 2, 3)]), dtype=torch.float32)[:, None]
    tension = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64).view(3, 1, 1, 1)
    out = biharmonic_fill(z * known, known, tension=tension)
    assert out.dtype == torch.float32
    for i, t_i in enumerate((0.0, 0.5, 1.0)):
        torch.testing.assert_close(out[i : i + 1], biharmonic_fill(z[i : i + 1] * known[i : i + 1], known[i : i + 1], tension=t_i),
                                   rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match=r"one per map \(shape \(3, 1, 1, 1\)\)"):
        biharmonic_fill(z * known, known, tension=torch.zeros(3, 1, 1))


def test_a_bool_or_float64_mask_fills_like_the_maps_own_dtype():
    z = t(smooth_field(16, 4))
    known = torch.as_tensor(rings(16, 4))[None, None]
    expected = biharmonic_fill(z * known, known.float())
    for mask in (known, known.double()):
        out = biharmonic_fill(z * known, mask)
        assert out.dtype == torch.float32
        torch.testing.assert_close(out, expected, rtol=0, atol=0)


def test_the_pyramid_has_its_levels_of_weighted_means_observed_where_any_fine_cell_is():
    """``_pyramid``: exactly ``levels`` levels, each (rounding up) half the one below; a coarse
    cell is the mean of its observed fine cells, observed when any of them is (17 -> 9 -> 5)."""
    from warp_terrain.models.biharmonic import _pyramid

    height = torch.zeros(1, 1, 17, 17)
    mask = torch.zeros(1, 1, 17, 17)
    height[..., 0, 0], height[..., 0, 1], height[..., 1, 0] = 1.0, 2.0, 6.0  # (1, 1) unobserved
    mask[..., 0, 0] = mask[..., 0, 1] = mask[..., 1, 0] = 1.0
    height[..., 16, 16], mask[..., 16, 16] = 5.0, 1.0  # the ceil-mode edge block: one cell
    height[..., 4, 4] = 9.0  # unobserved: never counted
    levels = _pyramid(height, mask, pyramid_levels(17))
    assert [v.shape[-1] for v, _ in levels] == [17, 9, 5] and all(v.shape == k.shape for v, k in levels)
    value, known = levels[1]
    assert value[0, 0, 0, 0] == 3.0 and value[0, 0, 8, 8] == 5.0 and value[0, 0, 2, 2] == 0.0
    assert int(known.sum()) == 2 and known[0, 0, 0, 0] == known[0, 0, 8, 8] == 1.0
    value, known = levels[2]
    assert value[0, 0, 0, 0] == 3.0 and value[0, 0, 4, 4] == 5.0 and int(known.sum()) == 2


def test_observed_plane_is_the_least_squares_plane():
    rng = np.random.default_rng(12)
    z = rng.normal(size=(30, 40))
    known = rng.random((30, 40)) < 0.3
    r, c = np.mgrid[:30, :40]
    basis = np.column_stack([r[known], c[known], np.ones(known.sum())])
    coef, *_ = np.linalg.lstsq(basis, z[known], rcond=None)
    expected = coef[0] * r + coef[1] * c + coef[2]
    np.testing.assert_allclose(observed_plane(t(z), t(known))[0, 0].numpy(), expected, rtol=0, atol=1e-4)


def test_observed_plane_fits_each_map_of_a_batch_on_its_own():
    """Three maps, each with its own plane and its own cells (one a single row: its mean): each
    is what it is alone, not a fit pooled over the batch."""
    r, c = torch.meshgrid(torch.arange(12.0), torch.arange(16.0), indexing="ij")
    z = torch.stack([0.3 * r - 0.2 * c + 5.0, -1.1 * r + 0.05 * c - 2.0, 0.0 * r + 7.0 * c])[:, None]
    mask = torch.zeros(3, 1, 12, 16)
    mask[0, 0, ::3, ::2] = 1.0
    mask[1, 0, 1::4, 3::5] = 1.0
    mask[2, 0, 6, :] = 1.0
    out = observed_plane(z * mask, mask)
    torch.testing.assert_close(out[:2], z[:2], rtol=0, atol=1e-4)  # planes come back exactly
    torch.testing.assert_close(out[2], torch.full_like(out[2], float(z[2, 0, 6].mean())), rtol=0, atol=1e-4)
    for b in range(3):
        torch.testing.assert_close(out[b:b + 1], observed_plane((z * mask)[b:b + 1], mask[b:b + 1]), rtol=0, atol=1e-6)


def test_observed_plane_falls_back_to_the_mean_on_a_line_or_one_cell():
    z = torch.arange(100.0).view(1, 1, 10, 10)
    line = torch.zeros(1, 1, 10, 10)
    line[..., 4, :] = 1.0  # one row: the slope across it is unknown
    np.testing.assert_allclose(observed_plane(z, line).numpy(), z[..., 4, :].mean().item(), atol=1e-4)
    one = torch.zeros(1, 1, 10, 10)
    one[..., 2, 3] = 1.0
    np.testing.assert_allclose(observed_plane(z, one).numpy(), 23.0, atol=1e-4)


def model_config(**overrides) -> ModelConfig:
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=4, unet_depth=3, height_scale_min=0.05,
                      base_fill="biharmonic", height_reference="plane", start_from_fill=True, uncertainty=True)
    for key, value in overrides.items():
        setattr(cfg, key, value)
    return cfg.validate()


def condition(seed: int = 13, size: int = 40) -> torch.Tensor:
    z, known = smooth_field(size, seed), framed(size, seed + 1)
    r, c = np.mgrid[:size, :size]
    z = z + 0.4 * r  # a steep tilt: 16 m across the map
    return torch.cat([t(z * known), t(known)], dim=1)


@pytest.mark.parametrize("refine", [0, 2])
def test_untrained_model_starting_from_the_fill_is_the_fill(refine):
    x = condition()
    out = build_generator(model_config(refine=refine)).eval()(x)
    torch.testing.assert_close(out[:, :1], biharmonic_fill(x[:, :1], x[:, 1:]), rtol=0, atol=0)


def test_plane_reference_makes_the_net_blind_to_tilt():
    """With the plane reference the net sees the same input when a plane is added to the scan
    (on a framed map the thin plate keeps planes), so its correction and its uncertainty do not
    change; with the mean reference they do."""
    torch.manual_seed(0)
    x = condition()
    r, c = torch.meshgrid(torch.arange(40.0), torch.arange(40.0), indexing="ij")
    tilt = (0.7 * r - 0.3 * c + 5.0)[None, None]  # 39 m across the map
    tilted = torch.cat([x[:, :1] + tilt * x[:, 1:], x[:, 1:]], dim=1)

    def correction(g, cond):
        with torch.no_grad():
            out = g(cond)
        return out[:, :1] - g.base_fill(cond[:, :1], cond[:, 1:]), out[:, 1:]

    g = build_generator(model_config(start_from_fill=False, observed_bound=0.0)).eval()
    (level, level_sigma), (steep, steep_sigma) = correction(g, x), correction(g, tilted)
    assert level.abs().max() > 0.01  # the net does correct
    torch.testing.assert_close(steep, level, rtol=0, atol=1e-3)
    torch.testing.assert_close(steep_sigma, level_sigma, rtol=0, atol=3e-3)
    mean_model = build_generator(model_config(start_from_fill=False, observed_bound=0.0, height_reference="mean")).eval()
    mean_model.load_state_dict(g.state_dict())
    assert (correction(mean_model, tilted)[0] - correction(mean_model, x)[0]).abs().max() > 0.05


def test_observed_cells_move_at_most_the_bound():
    torch.manual_seed(1)
    g = FillResidualGenerator(torch.nn.Conv2d(2, 1, 1), base="biharmonic", reference="plane", observed_bound=0.1)
    with torch.no_grad():
        g.net.weight.fill_(50.0)  # a wild correction
        x = condition()
        out = g(x)
    observed = x[:, 1:] > 0
    moved = (out - x[:, :1]).abs()
    assert moved[observed].max() <= 0.1 + 1e-6 and moved[~observed].max() > 1.0


def test_a_noisy_scans_observed_cells_may_move_by_its_noise():
    """``noise_bound=3``: the bound on observed cells is ``max(observed_bound, 3 scan_noise)`` per
    map. A wild correction moves the observed cells of a scan with 0.2 m of noise by up to that
    bound (about 0.6 m, reached within 1 mm), those of the same scan without noise by 0.1 m at
    most, as without ``noise_bound``; unobserved cells stay free."""
    from warp_terrain.models.noise import scan_noise

    torch.manual_seed(1)
    g = FillResidualGenerator(torch.nn.Conv2d(2, 1, 1), base="biharmonic", reference="plane", observed_bound=0.1,
                              noise_bound=3.0)
    clean = condition()
    noisy = clean.clone()
    noisy[:, :1] += 0.2 * torch.randn_like(clean[:, :1]) * clean[:, 1:]
    with torch.no_grad():
        g.net.weight.fill_(50.0)  # a wild correction
        bounds = []
        for x in (clean, noisy):
            observed = x[:, 1:] > 0
            moved = (g(x) - x[:, :1]).abs()
            bound = max(0.1, 3.0 * float(scan_noise(x[:, :1], x[:, 1:])))
            assert moved[observed].max() <= bound + 1e-6 and moved[observed].max() > bound - 1e-3 and moved[~observed].max() > 1.0
            bounds.append(bound)
            # a caller that has the scan's noise already (the Reconstructor, once for eight orientations) passes it
            assert torch.equal(g(x, noise=scan_noise(x[:, :1], x[:, 1:])), g(x))
    assert bounds[0] == 0.1 and 0.5 < bounds[1] < 0.7
    with pytest.raises(ValueError, match="noise_bound: needs observed_bound > 0"):
        FillResidualGenerator(torch.nn.Conv2d(2, 1, 1), noise_bound=3.0)


@pytest.mark.parametrize("refine,screened,noise_bound", [(0, 0.0, 0.0), (2, 0.1, 3.0)])
def test_generator_exports_to_onnx_and_matches(tmp_path, refine, screened, noise_bound):
    onnxruntime = pytest.importorskip("onnxruntime")
    g = build_generator(model_config(start_from_fill=False, refine=refine, screened_input=screened, observed_bound=0.1 if noise_bound else 0.0,
                                     observed_bound_noise=noise_bound)).eval()
    # 15 cells: two pyramid levels (8 and 15), the coarse fill upsampled to 16 and cropped, the
    # U-Net's input padded to 16 and cropped back: every kind of op of a 121-cell graph, exported
    # in 47 s for both cases against 115 s at 48 cells (measured beside a training run); with the
    # noise-widened bound, a noisy scan (the bound then above observed_bound: the sort and gather of
    # the scan's noise in the graph)
    x = condition(size=15)
    if noise_bound:
        x[:, :1] += 0.3 * torch.randn(x[:, :1].shape, generator=torch.Generator().manual_seed(5)) * x[:, 1:]
    path = tmp_path / "g.onnx"
    torch.onnx.export(g, (x,), str(path), input_names=["condition"], output_names=["out"], dynamo=False)
    got = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"condition": x.numpy()})[0]
    with torch.no_grad():
        np.testing.assert_allclose(got, g(x).numpy(), rtol=0, atol=1e-3)


def test_the_refine_head_lets_one_input_cell_reach_its_own_output_cell():
    """pix2pix's outermost level makes the output by a stride-2 transposed convolution of
    half-resolution features: two neighbouring input cells land in the same 2x2 block of
    features. With the refine head the input itself is convolved at full resolution, so the
    output at a cell depends on that cell's input through a 3x3 path: a change confined to one
    cell moves the output there by the head's direct weights (checked against the head alone)."""
    from warp_terrain.models.unet import UNet

    torch.manual_seed(3)
    net = UNet(2, 1, ngf=4, depth=3, norm="none", dropout=0.0, refine=1).eval()
    assert net.head is not None and [type(m).__name__ for m in net.head.body] == ["Conv2d", "ReLU"]
    x = torch.randn(1, 2, 16, 16)
    y = x.clone()
    y[0, 0, 7, 8] += 1.0
    with torch.no_grad():
        features = net.model(x)  # 16 is a multiple of 2**3: no padding, no crop
        direct = net.head(features, y) - net.head(features, x)  # the head's own path from the input
        total = net(y) - net(x)
    assert direct[0, 0, 7, 8].abs() > 0 and direct.abs()[0, 0].sum() == direct[0, 0, 6:9, 7:10].abs().sum()
    assert torch.isfinite(total).all() and (total - direct).abs().max() < total.abs().max()
    with pytest.raises(ValueError, match="refine"):
        UNet(2, 1, ngf=4, depth=3, refine=-1)
    with pytest.raises(ValueError, match="refine=2: only the unet generator"):
        ModelConfig(name="paper", refine=2).validate()


def test_the_screened_input_is_the_screened_fill_about_the_mean_and_widens_a_net_to_the_same_model():
    """``screened_input = k``: the net's third input is ``screened_fill`` (the thin plate of the
    heights about their observed mean, screened by k, plus the mean) about the same reference and
    scale as the base fill; a state dict of the same net without it widens by a zero column to a
    model that predicts exactly what the narrow one did."""
    from warp_terrain.models.fill import mean_observed, screened_fill, widen_to_screened_input

    torch.manual_seed(4)
    x = condition(size=48)
    scan, mask = x[:, :1], x[:, 1:]
    mean = mean_observed(scan, mask)
    torch.testing.assert_close(screened_fill(scan, mask, 0.1), biharmonic_fill(scan - mean, mask, screening=0.1) + mean,
                               rtol=0, atol=0)
    narrow = build_generator(model_config(start_from_fill=False, refine=1)).eval()
    wide = build_generator(model_config(start_from_fill=False, refine=1, screened_input=0.1)).eval()
    seen = []
    wide.net.register_forward_pre_hook(lambda _, args: seen.append(args[0]))
    wide.load_state_dict(widen_to_screened_input(narrow.state_dict(), wide))
    with torch.no_grad():
        torch.testing.assert_close(wide(x), narrow(x), rtol=0, atol=0)
    reference = observed_plane(scan, mask)
    scale = ((((scan - reference) ** 2) * mask).sum() / mask.sum()).sqrt().clamp_min(0.05)
    torch.testing.assert_close(seen[0][:, 2:], (screened_fill(scan, mask, 0.1) - reference) / scale, rtol=0, atol=1e-5)
    with torch.no_grad():  # the new column does reach the output
        next(m for m in wide.net.modules() if isinstance(m, torch.nn.Conv2d)).weight[:, 2:].fill_(1.0)
        assert (wide(x) - narrow(x)).abs().max() > 1e-3
    other = build_generator(model_config(start_from_fill=False, refine=1, ngf=8, screened_input=0.1))
    with pytest.raises(ValueError, match="cannot widen to .* by one input channel"):
        widen_to_screened_input(narrow.state_dict(), other)


def test_widening_takes_one_more_input_column_and_refuses_anything_else():
    """Only a 4-D weight that lacks exactly the last input column widens (zeros there); another
    shape, a vector that differs, or a key the generator lacks is refused naming it."""
    from warp_terrain.models.fill import widen_to_screened_input

    target = torch.nn.Conv2d(3, 4, 3)
    narrow = torch.nn.Conv2d(2, 4, 3).state_dict()
    wide = widen_to_screened_input(narrow, target)
    assert wide["weight"].shape == (4, 3, 3, 3) and torch.equal(wide["weight"][:, :2], narrow["weight"])
    assert not wide["weight"][:, 2].any() and torch.equal(wide["bias"], narrow["bias"])
    for bad in (torch.nn.Conv2d(2, 5, 3), torch.nn.Conv2d(2, 4, 5), torch.nn.Conv2d(1, 4, 3)):  # outputs, kernel, two columns
        with pytest.raises(ValueError, match=r"weight: shape .* cannot widen to \(4, 3, 3, 3\) by one input channel"):
            widen_to_screened_input(bad.state_dict(), target)
    with pytest.raises(ValueError, match=r"bias: shape \(5,\) cannot widen to \(4,\)"):
        widen_to_screened_input({"bias": torch.zeros(5)}, target)
    with pytest.raises(ValueError, match="^not in the widened generator: extra, more$"):
        widen_to_screened_input({**narrow, "more": torch.zeros(1), "extra": torch.zeros(1)}, target)


def test_config_names_bad_fill_and_reference():
    for key, value in (("base_fill", "kriging"), ("height_reference", "median"), ("observed_bound", -1.0),
                       ("screened_input", -0.1), ("screened_input", float("inf")), ("observed_bound_noise", -1.0),
                       ("observed_bound_noise", 3.0)):  # the last: without observed_bound
        with pytest.raises(ValueError, match=key):
            model_config(**{key: value})


def test_with_the_plane_fill_the_whole_model_moves_with_any_added_plane():
    """``plane_biharmonic`` + the plane reference: adding a plane to the scan changes nothing the
    net sees and the fill moves by that plane, on any mask (not only a framed one)."""
    torch.manual_seed(2)
    g = build_generator(model_config(start_from_fill=False, base_fill="plane_biharmonic")).eval()
    z, known = t(smooth_field(48, 21)), t(rings(48, 22))
    r, c = torch.meshgrid(torch.arange(48.0), torch.arange(48.0), indexing="ij")
    tilt = (0.5 * r + 0.2 * c - 3.0)[None, None]  # 34 m across the map
    with torch.no_grad():
        a = g(torch.cat([z * known, known], dim=1))
        b = g(torch.cat([(z + tilt) * known, known], dim=1))
    torch.testing.assert_close(b[:, :1], a[:, :1] + tilt, rtol=0, atol=2e-4 * 34)
    torch.testing.assert_close(b[:, 1:], a[:, 1:], rtol=0, atol=1e-3)


def test_fill_relative_weights_are_the_inverse_fill_errors_normalised():
    """Two maps whose fills err by 0.02 m and 0.5 m on their unobserved cells (observed cells,
    however wrong, do not count; the 1 cm floor applies to a perfect fill) weigh 1 / error,
    scaled to a mean of 1."""
    from warp_terrain.models.fill import fill_relative_weight

    target = torch.zeros(3, 1, 4, 4)
    mask = torch.zeros(3, 1, 4, 4)
    mask[:, :, 0, :] = 1.0
    base = torch.zeros(3, 1, 4, 4)
    base[0] = 0.02
    base[1, :, 1:] = -0.5
    base[:, :, 0, :] = 9.0  # observed cells: not scored
    w = fill_relative_weight(base, target, mask, floor=0.01).flatten()
    inverse = torch.tensor([1 / 0.02, 1 / 0.5, 1 / 0.01])
    torch.testing.assert_close(w, inverse / inverse.mean(), rtol=1e-6, atol=0)


def test_the_scripted_solve_is_the_eager_loop_bit_for_bit():
    """``conjugate_gradient`` runs as TorchScript outside ONNX export: for the membrane, the
    thin plate, a fractional tension and one tension per map, screened or not, in float32 and
    float64, it returns exactly what the eager loop (what the export traces) returns."""
    g = torch.Generator().manual_seed(0)
    for dtype in (torch.float32, torch.float64):
        for size in (8, 31):
            u = torch.randn(3, 1, size, size, generator=g, dtype=dtype)
            free = (torch.rand(3, 1, size, size, generator=g) < 0.7).to(dtype)
            for tension in (0.0, 1.0, 0.3, torch.tensor([0.0, 0.5, 1.0], dtype=dtype).view(-1, 1, 1, 1)):
                for k2 in (0.0, 0.01):
                    want = _eager_cg(u, free, 12, tension, k2)
                    assert torch.equal(conjugate_gradient(u, free, 12, tension, k2), want), (dtype, size, tension, k2)
                    assert float((want - u).abs().max()) > 0  # the steps did move the map
