"""Thin-plate (biharmonic) inpainting as torch ops: a classical fill the network can start from.

``biharmonic_fill(height, mask)`` returns the surface ``u`` that keeps every observed cell and
minimises, over the unobserved ones,

    E(u) = (1 - tension) * sum |L u|^2 + tension * sum |grad u|^2

where ``L`` is the 5-point Laplacian on the interior cells (a cell with all four neighbours)
and ``grad`` the forward differences (grid units; h = 1). ``tension = 0`` is the thin plate:
its minimiser solves the biharmonic equation ``L^T L u = 0`` in the holes, like
``skimage.restoration.inpaint_biharmonic``, and with the Laplacian taken only where it is
defined the map's border is a free edge, so a slope runs on past the last observation instead
of flattening (a plane is reproduced exactly, at any hole shape). A little tension (GMT's
``surface -T``) damps the overshoot of the thin plate next to steps; ``tension = 1`` is the
membrane (Laplace interpolation: each free cell the mean of its neighbours, as the
``harmonic`` baseline), which never overshoots: the better fill of rough ground and noisy scans.

``screening = k > 0`` (1 / cells) adds ``2 k^2 |grad u|^2 + k^4 |u|^2`` to the thin plate's
part: with ``tension = 0`` the energy of a Matern field's SPDE (Lindgren et al. 2011: precision
``(k^2 - L)^2``), whose fill returns to zero within about ``1 / k`` cells of the last
observation instead of running a slope on (pass heights about a reference to return to it).

The linear system ``A_FF u_F = -A_FK h_K`` (F: free cells, K: observed; ``A = (1-t) L^T L + t
G^T G``, symmetric positive definite once one cell is observed) is solved matrix-free by
conjugate gradients, cascadic multigrid style: heights and masks are averaged down a pyramid
(as the push-pull fill), the coarsest level is solved first, and each finer level starts from
the bilinear upsampling of the level above and runs a fixed number of CG steps. Every op is a
convolution, a pooling, an interpolation or an elementwise op with a fixed count of steps: it is
batched on the device, differentiable (not needed: it has no parameters) and exports to ONNX
(the loops unroll). Outside export the CG loop runs as TorchScript, the same ops bit for bit:
a small map's solve costs the launches of its ops, not their arithmetic, and the interpreter
launches them faster (the check's six-map solve: min 22.5 -> 15.6 ms on two threads,
``tools/probes/cg_script_ab.py``). A map with no observed cell comes back as zeros.

The cascade never returns to a coarse level, so in gaps much wider than its finest level's CG
can bridge (between the rings of a sparse 32-beam scan) it stops short of the thin plate.
``v_cycles`` solves such a fill further by multigrid V-cycles (the residual's equation down
the same pyramid and back); the self-check runs one on the thin plates it weighs.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

#: CG steps per pyramid level, coarsest first; the finest level gets the last entry (a map of
#: 121 cells has five levels: 8, 16, 31, 61, 121).
DEFAULT_STEPS = (64, 48, 32, 24, 24)
#: Coarsest level's size (cells along the longer side) of the pyramid.
COARSEST = 8


def _laplacian(u: torch.Tensor) -> torch.Tensor:
    """The 5-point Laplacian with replicated edges: the graph Laplacian of the grid (Neumann).
    Four shifted slices of the padded map, not a 3x3 convolution: 1.5x faster for one map on
    the CPU, 5x for eight (one input channel leaves a convolution nothing to vectorise)."""
    p = F.pad(u, (1, 1, 1, 1), mode="replicate")
    return torch.add(p[..., :-2, 1:-1] + p[..., 2:, 1:-1] + p[..., 1:-1, :-2] + p[..., 1:-1, 2:], u, alpha=-4.0)


def _operator(u: torch.Tensor, tension: float | torch.Tensor, k2: float) -> torch.Tensor:
    """``A u = (1 - t) (L L u - 2 k2 L u + k2^2 u) - t L u``: ``L`` is symmetric, so this is the
    gradient of E / 2. ``t`` a number, or a (B, 1, 1, 1) tensor: each map its own tension;
    ``k2`` the squared screening in this level's cells."""
    lap = _laplacian(u)
    if isinstance(tension, (int, float)) and tension == 1:
        return -lap
    out = _laplacian(lap)
    if k2 > 0:
        out = out - 2.0 * k2 * lap + (k2 * k2) * u
    return out if isinstance(tension, (int, float)) and tension == 0 else (1.0 - tension) * out - tension * lap


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(dim=(1, 2, 3), keepdim=True)


def conjugate_gradient(u: torch.Tensor, free: torch.Tensor, steps: int, tension: float | torch.Tensor,
                       k2: float) -> torch.Tensor:
    """``steps`` CG iterations on the free cells of ``u`` (the others are held), from ``u``;
    ``k2`` the squared screening in ``u``'s cells (0: none).

    Where a map has converged (``r = 0``, so ``p = 0``) both step sizes are ``0 / tiny = 0``:
    no branch, so a batch runs the same ops for every map (and exports as a plain graph).

    Run as TorchScript (:func:`_scripted_cg`, the same ops in the same order: bit-identical),
    except while tracing (ONNX export) or under ``torch.compile``, which get the eager loop to
    unroll: a small map's solve is bound by the cost of launching its ops, which the
    interpreter cuts by about a third."""
    if torch.jit.is_tracing() or torch.onnx.is_in_onnx_export() or torch.compiler.is_compiling():
        return _eager_cg(u, free, steps, tension, k2)
    if isinstance(tension, torch.Tensor):
        return _scripted_cg(u, None, free, steps, 1.0 - tension, tension, float(k2), MIXED)
    kind = MEMBRANE if tension == 1 else THIN_PLATE if tension == 0 else MIXED
    # a number's 1 - t in double, then rounded, as the eager op's scalar is
    a, t = (torch.tensor(float(x), dtype=u.dtype, device=u.device) for x in (1.0 - tension, tension))
    return _scripted_cg(u, None, free, steps, a, t, float(k2), kind)


#: The operator's forms in :func:`_scripted_cg`: ``-L`` (a tension of exactly 1), the screened
#: thin plate (exactly 0), and their mix under a tension per map.
MEMBRANE, THIN_PLATE, MIXED = 0, 1, 2


@torch.jit.script
def _scripted_laplacian(u: torch.Tensor) -> torch.Tensor:
    """:func:`_laplacian`, for TorchScript."""
    p = F.pad(u, [1, 1, 1, 1], mode="replicate")
    return torch.add(p[:, :, :-2, 1:-1] + p[:, :, 2:, 1:-1] + p[:, :, 1:-1, :-2] + p[:, :, 1:-1, 2:], u, alpha=-4.0)


@torch.jit.script
def _scripted_operator(u: torch.Tensor, a: torch.Tensor, t: torch.Tensor, k2: float, kind: int) -> torch.Tensor:
    """:func:`_operator` with ``a = 1 - t`` given: the same ops in the same order."""
    lap = _scripted_laplacian(u)
    if kind == 0:  # MEMBRANE (TorchScript reads no module globals)
        return -lap
    out = _scripted_laplacian(lap)
    if k2 > 0:
        out = out - 2.0 * k2 * lap + (k2 * k2) * u
    if kind == 1:  # THIN_PLATE
        return out
    return a * out - t * lap


@torch.jit.script
def _scripted_cg(u: torch.Tensor, b: torch.Tensor | None, free: torch.Tensor, steps: int, a: torch.Tensor, t: torch.Tensor,
                 k2: float, kind: int) -> torch.Tensor:
    """:func:`_eager_cg` as TorchScript: ``steps`` CG iterations on ``free * (A u - b) = 0`` from
    ``u`` (``b`` None: 0, the fill's own equation; a residual's right-hand side in a V-cycle)."""
    r = -free * _scripted_operator(u, a, t, k2, kind) if b is None else free * (b - _scripted_operator(u, a, t, k2, kind))
    p = r
    rr = (r * r).sum(dim=(1, 2, 3), keepdim=True)
    for _ in range(steps):
        ap = free * _scripted_operator(p, a, t, k2, kind)
        alpha = rr / (p * ap).sum(dim=(1, 2, 3), keepdim=True).clamp_min(1e-30)
        u = torch.addcmul(u, alpha, p)
        r = torch.addcmul(r, alpha, ap, value=-1.0)
        rr_new = (r * r).sum(dim=(1, 2, 3), keepdim=True)
        p = torch.addcmul(r, rr_new / rr.clamp_min(1e-30), p)
        rr = rr_new
    return u


def _eager_cg(u: torch.Tensor, free: torch.Tensor, steps: int, tension: float | torch.Tensor, k2: float) -> torch.Tensor:
    """:func:`conjugate_gradient` as plain torch ops (what ONNX export traces)."""
    r = -free * _operator(u, tension, k2)
    p = r
    rr = _dot(r, r)
    for _ in range(steps):
        ap = free * _operator(p, tension, k2)
        alpha = rr / _dot(p, ap).clamp_min(1e-30)
        u = torch.addcmul(u, alpha, p)  # fused: fewer ops per step (a small map's solve is op-bound)
        r = torch.addcmul(r, alpha, ap, value=-1.0)
        rr_new = _dot(r, r)
        p = torch.addcmul(r, rr_new / rr.clamp_min(1e-30), p)
        rr = rr_new
    return u


def _pyramid(height: torch.Tensor, mask: torch.Tensor, levels: int):
    """``[(heights, mask), ...]`` finest first: each level the weighted 2x2 mean of the one below;
    a coarse cell is observed when any of its fine cells is."""
    out = [(height * mask, mask)]
    value, weight = height * mask, mask
    for _ in range(levels - 1):
        value = F.avg_pool2d(value, 2, ceil_mode=True)
        weight = F.avg_pool2d(weight, 2, ceil_mode=True)
        known = (weight > 0).to(height.dtype)
        out.append((known * value / weight.clamp_min(1e-12), known))
    return out


def pyramid_levels(size: int, coarsest: int = COARSEST) -> int:
    """Levels of a pyramid over ``size`` cells halving (rounding up) down to ``<= coarsest``."""
    levels = 1
    while size > coarsest:
        size = -(-size // 2)
        levels += 1
    return levels


def biharmonic_fill(height: torch.Tensor, mask: torch.Tensor, tension: float | torch.Tensor = 0.0,
                    steps: tuple[int, ...] = DEFAULT_STEPS, screening: float = 0.0) -> torch.Tensor:
    """(B, 1, H, W) heights (m) and 0/1 mask -> heights with the unobserved cells filled by the
    thin plate under ``tension`` (in [0, 1]: 0 the thin plate, 1 the membrane; a number, or a
    (B, 1, 1, 1) tensor to solve maps of several tensions in one batch) and ``screening`` (k >= 0,
    1 / cells: the fill returns to 0 about 1 / k cells from the scan); observed cells are
    returned exactly."""
    if isinstance(tension, torch.Tensor):
        if tension.shape != (height.shape[0], 1, 1, 1) or not bool(((tension >= 0) & (tension <= 1)).all()):
            raise ValueError(f"tension must be in [0, 1], one per map (shape ({height.shape[0]}, 1, 1, 1)), got {tension.flatten().tolist()}")
        tension = tension.to(height.dtype)
    elif not 0.0 <= tension <= 1.0:
        raise ValueError(f"tension must be in [0, 1], got {tension}")
    if not steps:
        raise ValueError("steps must name at least one CG step count per level")
    if not 0.0 <= screening < float("inf"):
        raise ValueError(f"screening must be a finite number >= 0 (1 / cells), got {screening}")
    mask = mask.to(height.dtype)
    levels = _pyramid(height, mask, pyramid_levels(max(height.shape[-2:])))
    u = None
    for depth, (value, known) in enumerate(reversed(levels)):
        level = len(levels) - 1 - depth  # 0 = finest
        if u is None:  # coarsest: start from the mean observed height
            mean = _dot(value, known) / _dot(known, known).clamp_min(1.0)  # known is 0/1: sum(value)/count
            u = known * value + (1.0 - known) * mean
        else:
            up = F.interpolate(u, scale_factor=2.0, mode="bilinear", align_corners=False)
            up = up[..., : value.shape[-2], : value.shape[-1]]
            u = known * value + (1.0 - known) * up
        count = steps[min(depth, len(steps) - 1)] if level > 0 else steps[-1]
        u = conjugate_gradient(u, 1.0 - known, count, tension, (screening * 2.0**level) ** 2)
    return u


def biharmonic_fills(problems: list[tuple[torch.Tensor, torch.Tensor, float]]) -> list[torch.Tensor]:
    """The fills of several ``(heights, mask, tension)`` problems, each of (B_i, 1, H, W) maps,
    in order, as one batched :func:`biharmonic_fill` (each map under its problem's tension): on a
    CPU the coarse levels of a small map's solve cost their count of ops, not of maps, so one
    solve of six maps costs less than a solve of two and one of four."""
    if not problems:
        return []
    heights = torch.cat([h for h, _, _ in problems])
    masks = torch.cat([m.to(heights.dtype) for _, m, _ in problems])
    per_map = [float(t) for h, _, t in problems for _ in range(h.shape[0])]
    tension = per_map[0] if len(set(per_map)) == 1 else torch.tensor(per_map, dtype=heights.dtype, device=heights.device).view(-1, 1, 1, 1)
    return list(biharmonic_fill(heights, masks, tension=tension).split([h.shape[0] for h, _, _ in problems]))


#: Multigrid V-cycles (:func:`v_cycles`): CG steps before and after each coarse correction, and
#: CG steps on a cycle's coarsest level (at most ``COARSEST`` cells a side: a few dozen unknowns).
CYCLE_SMOOTHING = (4, 4)
CYCLE_COARSEST_STEPS = 16


@torch.jit.script
def _scripted_v_cycle(u: torch.Tensor, b: torch.Tensor, free: torch.Tensor, a: torch.Tensor, t: torch.Tensor, pre: int,
                      post: int, coarsest_steps: int, coarsest: int) -> torch.Tensor:
    """One multigrid V-cycle on ``free * (A u - b) = 0`` from ``u`` (:func:`v_cycles`)."""
    stack: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]] = []
    # kind 2 throughout: MIXED, the operator under a tension per map (TorchScript reads no module globals)
    while max(u.shape[-2], u.shape[-1]) > coarsest:
        u = _scripted_cg(u, b, free, pre, a, t, 0.0, 2)
        r = free * (b - _scripted_operator(u, a, t, 0.0, 2))
        stack.append((u, b, free, a, t, r))
        b = F.avg_pool2d(r, 2, ceil_mode=True)  # the residual per coarse cell
        free = 1.0 - F.max_pool2d(1.0 - free, 2, ceil_mode=True)  # free where all four fine cells are
        u = torch.zeros_like(b)
        a, t = a / 16.0, t / 4.0  # L L and L in coarse cells, as fine cells' residuals
    u = _scripted_cg(u, b, free, coarsest_steps, a, t, 0.0, 2)
    for i in range(len(stack) - 1, -1, -1):
        fine, b, free, a, t, r = stack[i]
        e = F.interpolate(u, scale_factor=2.0, mode="bilinear", align_corners=False)
        e = free * e[:, :, : fine.shape[-2], : fine.shape[-1]]
        # the step along the correction that minimises the energy: a cycle never raises it
        step = (r * e).sum(dim=(1, 2, 3), keepdim=True) / (e * free * _scripted_operator(e, a, t, 0.0, 2)).sum(
            dim=(1, 2, 3), keepdim=True).clamp_min(1e-30)
        u = _scripted_cg(torch.addcmul(fine, step, e), b, free, post, a, t, 0.0, 2)
    return u


def v_cycles(u: torch.Tensor, mask: torch.Tensor, cycles: int, tension: float | torch.Tensor = 0.0,
             smoothing: tuple[int, int] = CYCLE_SMOOTHING, coarsest_steps: int = CYCLE_COARSEST_STEPS) -> torch.Tensor:
    """``cycles`` multigrid V-cycles on a fill ``u`` (B, 1, H, W) of the cells ``mask`` leaves
    free (the observed cells held exactly): the fill of :func:`biharmonic_fill` solved further.

    The cascade starts each level from the one above but never returns to it, so the smooth part
    of its error in wide holes (between the rings of a sparse 32-beam scan: 12 % of the cells
    observed) decays only as fast as CG at the finest level reduces it. A cycle smooths with
    ``smoothing`` CG steps, hands the residual down the pyramid (a coarse cell free where all four
    of its fine cells are; the operator rescaled to coarse cells), solves the coarsest level with
    ``coarsest_steps`` CG steps and brings each level's correction back up, added at the step that
    minimises the energy and smoothed again, so no cycle raises the energy. Bilinear transfers
    are of a low order for a fourth-order operator: a cycle takes most of the cascade's error out
    of wide holes, not all of it (docs/transfer.md, stop 40). ``tension`` as :func:`biharmonic_fill`
    (no screening). TorchScript, like the cascade's CG: the self-check runs it on the thin plates
    it weighs, outside the exported model."""
    if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 0:
        raise ValueError(f"cycles must be an integer >= 0, got {cycles!r}")
    if len(smoothing) != 2 or min(smoothing) < 0 or coarsest_steps < 0:
        raise ValueError(f"smoothing must be two step counts >= 0 and coarsest_steps >= 0, got {smoothing!r}, {coarsest_steps!r}")
    if cycles == 0:
        return u
    if isinstance(tension, torch.Tensor):
        a, t = (1.0 - tension).to(u.dtype), tension.to(u.dtype)
    elif 0.0 <= tension <= 1.0:
        a, t = (torch.tensor(float(x), dtype=u.dtype, device=u.device) for x in (1.0 - tension, tension))
    else:
        raise ValueError(f"tension must be in [0, 1], got {tension}")
    free = 1.0 - mask.to(u.dtype)
    rhs = torch.zeros_like(u)
    for _ in range(cycles):
        u = _scripted_v_cycle(u, rhs, free, a, t, int(smoothing[0]), int(smoothing[1]), int(coarsest_steps), COARSEST)
    return u
