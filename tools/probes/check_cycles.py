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

The V-cycles are ``models.biharmonic.v_cycles`` (since stop 40 the shipped file runs one on the
check's thin plates: ``Reconstructor.check_cycles``; load the file with ``check_cycles=0`` to
compare, or name ``_cycles0`` in tools/real_ablation.py); this probe gives them to the membrane
too (``VC=cands``), to the base fill (``VC=all``), or swaps them for flexible CG (``VC=fpcg``).
"""

import os
import runpy
import sys

import torch

from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.models.biharmonic import COARSEST, CYCLE_COARSEST_STEPS, _scripted_operator, _scripted_v_cycle, biharmonic_fill, v_cycles
from warp_terrain.models.fill import FillResidualGenerator, observed_plane


def _coefficients(u: torch.Tensor, tension: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(1 - t, t)`` as tensors of ``u``'s dtype: a number, or one per map (B, 1, 1, 1)."""
    if isinstance(tension, torch.Tensor):
        return (1.0 - tension).to(u.dtype), tension.to(u.dtype)
    return tuple(torch.tensor(float(x), dtype=u.dtype, device=u.device) for x in (1.0 - tension, tension))


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
