"""Multigrid V-cycles after the thin plate's cascade, for the self-check's classical candidates
(and optionally the base fill the net corrects): does a better-converged fill make the check's
fallback as good as the classical fills on sparse scans? (docs/transfer.md, stop 39)

    VC=cands THREADS=2 python tools/probes/check_cycles.py unseen NAME=MODEL ...
    VC=all   THREADS=2 python tools/probes/check_cycles.py real --fills-cache outputs/fills_cache.json NAME=MODEL ...

``unseen`` runs tools/probes/unseen_real.py, ``real`` tools/real_ablation.py, with
``FillResidualGenerator.base_and_plain_fills`` patched: ``VC=cands`` gives the check's plain
fills (thin plate and membrane) ``CYCLES`` (default 1) V-cycles, ``VC=all`` the base fills too;
two bounds on what a better solve can buy: ``VC=converged`` solves the check's thin plate with
3,072 CG steps at the finest level (no V-cycle), ``VC=exact`` takes skimage's biharmonic and the
exact harmonic fill (``evaluation.BASELINES``) as the check's thin plate and membrane;
``VC=fpcg`` gives the check's plain fills ``CYCLES`` iterations of flexible CG preconditioned by
one V-cycle each (smoothing 2 + 2).

The cascade of ``models/biharmonic.py`` starts each level from the one above and never returns
to it, so the smooth part of its error in wide holes (between the rings of a sparse 32-beam
scan) decays only as fast as CG at the finest level reduces it. A V-cycle smooths with a few
CG steps, hands the residual down the pyramid (a coarse cell free where all four fine cells
are; the operator rescaled to coarse cells), solves the coarsest level, and adds each level's
correction back at the step that minimises the energy, so no cycle can raise it. Bilinear
transfers are of too low an order for a fourth-order operator: the pure thin plate converges
slowly (a tension > 0 fast), which is why this stays a probe.
"""

import os
import runpy
import sys

import torch
import torch.nn.functional as F

from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.models.biharmonic import COARSEST, _scripted_operator, biharmonic_fill
from warp_terrain.models.fill import FillResidualGenerator, observed_plane

#: V-cycles after the cascade: CG steps before and after each coarse correction, and CG steps
#: on a cycle's coarsest level (at most 8 cells a side: a few dozen unknowns).
CYCLE_SMOOTHING = (4, 4)
CYCLE_COARSEST_STEPS = 16  # the probe's figures: smoothing (4, 4), 16 steps, one cycle


@torch.jit.script
def _scripted_residual_cg(u: torch.Tensor, b: torch.Tensor, free: torch.Tensor, steps: int, a: torch.Tensor,
                          t: torch.Tensor) -> torch.Tensor:
    """``steps`` CG iterations on ``free * (A u - b) = 0`` from ``u``, ``A = a L L - t L``."""
    r = free * (b - _scripted_operator(u, a, t, 0.0, 2))
    p = r
    rr = (r * r).sum(dim=(1, 2, 3), keepdim=True)
    for _ in range(steps):
        ap = free * _scripted_operator(p, a, t, 0.0, 2)
        alpha = rr / (p * ap).sum(dim=(1, 2, 3), keepdim=True).clamp_min(1e-30)
        u = torch.addcmul(u, alpha, p)
        r = torch.addcmul(r, alpha, ap, value=-1.0)
        rr_new = (r * r).sum(dim=(1, 2, 3), keepdim=True)
        p = torch.addcmul(r, rr_new / rr.clamp_min(1e-30), p)
        rr = rr_new
    return u


@torch.jit.script
def _scripted_v_cycle(u: torch.Tensor, b: torch.Tensor, free: torch.Tensor, a: torch.Tensor, t: torch.Tensor, pre: int, post: int,
                      coarsest_steps: int, coarsest: int) -> torch.Tensor:
    """One multigrid V-cycle on ``free * (A u - b) = 0`` from ``u`` (:func:`v_cycles`)."""
    stack: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]] = []
    while max(u.shape[-2], u.shape[-1]) > coarsest:
        u = _scripted_residual_cg(u, b, free, pre, a, t)
        r = free * (b - _scripted_operator(u, a, t, 0.0, 2))
        stack.append((u, b, free, a, t, r))
        b = F.avg_pool2d(r, 2, ceil_mode=True)  # the residual per coarse cell
        free = 1.0 - F.max_pool2d(1.0 - free, 2, ceil_mode=True)  # free where all four fine cells are
        u = torch.zeros_like(b)
        a, t = a / 16.0, t / 4.0  # L L and L in coarse cells, as fine cells' residuals
    u = _scripted_residual_cg(u, b, free, coarsest_steps, a, t)
    for i in range(len(stack) - 1, -1, -1):
        fine, b, free, a, t, r = stack[i]
        e = F.interpolate(u, scale_factor=2.0, mode="bilinear", align_corners=False)
        e = free * e[:, :, : fine.shape[-2], : fine.shape[-1]]
        # the step along the correction that minimises the energy: a cycle never makes it worse
        step = (r * e).sum(dim=(1, 2, 3), keepdim=True) / (e * free * _scripted_operator(e, a, t, 0.0, 2)).sum(
            dim=(1, 2, 3), keepdim=True).clamp_min(1e-30)
        u = _scripted_residual_cg(torch.addcmul(fine, step, e), b, free, post, a, t)
    return u


def _coefficients(u: torch.Tensor, tension: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(1 - t, t)`` as tensors of ``u``'s dtype: a number, or one per map (B, 1, 1, 1)."""
    if isinstance(tension, torch.Tensor):
        return (1.0 - tension).to(u.dtype), tension.to(u.dtype)
    return tuple(torch.tensor(float(x), dtype=u.dtype, device=u.device) for x in (1.0 - tension, tension))


def v_cycles(u: torch.Tensor, mask: torch.Tensor, cycles: int, tension: float | torch.Tensor = 0.0,
             smoothing: tuple[int, int] = CYCLE_SMOOTHING, coarsest_steps: int = CYCLE_COARSEST_STEPS) -> torch.Tensor:
    """``cycles`` multigrid V-cycles on a fill ``u`` (B, 1, H, W) of the cells ``mask`` leaves
    free, the observed cells held: a fill the cascade of :func:`biharmonic_fill` left short of
    convergence, solved further. The cascade starts each level from the one above but never
    returns to it, so the smooth part of its error in wide holes (between the rings of a sparse
    scan) decays only as fast as CG at the finest level reduces it; a cycle smooths with
    ``smoothing`` CG steps, hands the residual down the pyramid (a coarse cell free where all
    four of its fine cells are; the operator rescaled to the coarse cells), solves the coarsest
    level and brings each level's correction back up, each added at the step that minimises the
    energy, so no cycle can raise it. ``tension`` as :func:`biharmonic_fill` (no screening).
    TorchScript: the check's candidates run it at inference, not the exported model."""
    if not (isinstance(cycles, int) and cycles >= 0):
        raise ValueError(f"cycles must be an integer >= 0, got {cycles!r}")
    if cycles == 0:
        return u
    a, t = _coefficients(u, tension)
    free = 1.0 - mask.to(u.dtype)
    for _ in range(cycles):
        u = _scripted_v_cycle(u, torch.zeros_like(u), free, a, t, int(smoothing[0]), int(smoothing[1]), int(coarsest_steps), COARSEST)
    return u


def flexible_pcg(u: torch.Tensor, mask: torch.Tensor, iterations: int, tension: float | torch.Tensor = 0.0,
                 smoothing: tuple[int, int] = (2, 2), coarsest_steps: int = CYCLE_COARSEST_STEPS) -> torch.Tensor:
    """``iterations`` of flexible preconditioned CG on the fill ``u``, each residual preconditioned
    by one V-cycle from zero (a CG smoother makes the cycle nonlinear, hence the flexible,
    Polak-Ribiere, direction update)."""
    a, t = _coefficients(u, tension)
    free = 1.0 - mask.to(u.dtype)

    def precondition(r):
        return _scripted_v_cycle(torch.zeros_like(r), r, free, a, t, int(smoothing[0]), int(smoothing[1]), int(coarsest_steps), COARSEST)

    def dot(x, y):
        return (x * y).sum(dim=(1, 2, 3), keepdim=True)

    r = -free * _scripted_operator(u, a, t, 0.0, 2)
    z = precondition(r)
    p, rz = z, dot(r, z)
    for _ in range(iterations):
        ap = free * _scripted_operator(p, a, t, 0.0, 2)
        alpha = rz / dot(p, ap).clamp_min(1e-30)
        u = u + alpha * p
        r_new = r - alpha * ap
        z = precondition(r_new)
        p = z + dot(z, r_new - r) / rz.clamp_min(1e-30) * p
        r, rz = r_new, dot(r_new, z)
    return u


def patched(original, mode: str, cycles: int):
    def base_and_plain_fills(self, scan, mask, tensions=(), count=None):
        base, plain = original(self, scan, mask, tensions, count)
        count = scan.shape[0] if count is None else count
        if mode == "all":
            plane = observed_plane(scan, mask)
            base = v_cycles(base - plane, mask, cycles) + plane
        if tensions and mode in ("converged", "exact"):
            fills = []
            for t, p in zip(tensions, plain):
                if mode == "exact":
                    p = BASELINES["biharmonic" if t == 0 else "harmonic"](scan[:count], mask[:count]).to(p.dtype)
                elif t == 0:
                    p = biharmonic_fill(scan[:count], mask[:count], steps=(64, 48, 32, 24, 3072))
                fills.append(p)
            return base, torch.stack(fills)
        if tensions:
            k = len(tensions)
            flat = plain.reshape(k * count, *plain.shape[2:])
            tension = torch.tensor([float(t) for t in tensions for _ in range(count)], dtype=scan.dtype).view(-1, 1, 1, 1)
            solve = flexible_pcg if mode == "fpcg" else v_cycles
            plain = solve(flat, mask[:count].repeat(k, 1, 1, 1), cycles, tension=tension).reshape(plain.shape)
        return base, plain

    return base_and_plain_fills


if __name__ == "__main__":
    tools = {"unseen": "tools/probes/unseen_real.py", "real": "tools/real_ablation.py"}
    if len(sys.argv) < 2 or sys.argv[1] not in tools:
        sys.exit("usage: [VC=cands|all|converged|exact|fpcg] [CYCLES=N] python tools/probes/check_cycles.py unseen|real ARGS ...")
    mode = os.environ.get("VC", "cands")
    if mode not in ("cands", "all", "converged", "exact", "fpcg"):
        sys.exit(f"VC must be cands, all, converged, exact or fpcg, got {mode!r}")
    FillResidualGenerator.base_and_plain_fills = patched(FillResidualGenerator.base_and_plain_fills, mode, int(os.environ.get("CYCLES", "1")))
    tool = tools[sys.argv[1]]
    sys.path.insert(0, "tools")
    sys.argv = [tool] + sys.argv[2:]
    runpy.run_path(tool, run_name="__main__")
