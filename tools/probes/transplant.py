"""Probe (docs/transfer.md): the net's correction laid on the fill the check picks.

The shipped check blends ``fill + w (model - fill)``, ``fill`` the classical fill it picked (the
base fill or the thin plate, moved towards the membrane). Where the membrane wins (rough ground,
noisy scans) ``model - fill`` is the thin plate's departure from the membrane plus the net's
correction, one candidate weighed as a whole. Here the net's own correction ``c = model - base``
(``base`` the base fill the net corrected) is a candidate of its own:

- ``_tp``: the map is ``fill + w c``, ``w`` the least-squares weight of ``c`` on the hidden cells;
- ``_sel``: per map, whichever of the shipped blend and ``_tp``'s errs less on the hidden cells
  (near and far alike, one choice per map);
- ``_joint``: ``fill + a (model - fill) + b c``, ``(a, b)`` the least-squares pair on the hidden
  cells within [0, 1]^2;

each with the shipped reach (near / far weights, the correction kept whole far from the scan).
``_splitNF`` (``split_maps``) instead takes the map's near part (the check's ramp, 2 -> 8 cells
from the scan) from rule ``N`` and its far part from rule ``F``, to tell where a rule gains.
Without a token the check is the shipped one.

usage: THREADS=1 python tools/probes/transplant.py --fills-cache outputs/fills_cache.json \
           T_check_reach_keepfar_sigma_membrane_tp=shipped
"""

import re

import torch
from common import run

from warp_terrain.inference import reconstructor
from warp_terrain.inference import selfcheck as check

PROBE: dict = {}


def joint_weights(x1, x2, r, cells):
    """(B,1,1,1) pair ``(a, b)`` in [0, 1]^2 minimising ``|r - a x1 - b x2|^2`` over ``cells``: the
    unconstrained least squares if it lies in the box, else the best point on the box's edges
    (each edge a one-dimensional least squares, clamped)."""
    h = cells.to(r.dtype)
    s = lambda u, v: (u * v * h).sum(dim=(2, 3), keepdim=True)  # noqa: E731
    a11, a12, a22, b1, b2 = s(x1, x1), s(x1, x2), s(x2, x2), s(x1, r), s(x2, r)
    det = a11 * a22 - a12 * a12
    q = lambda a, b: a * a * a11 + 2 * a * b * a12 + b * b * a22 - 2 * a * b1 - 2 * b * b2  # noqa: E731
    safe = lambda num, den: torch.where(den > 0, num / den.clamp_min(1e-30), torch.zeros_like(num)).clamp(0, 1)  # noqa: E731
    zero, one = torch.zeros_like(a11), torch.ones_like(a11)
    candidates = [
        (zero, safe(b2, a22)),
        (one, safe(b2 - a12, a22)),
        (safe(b1, a11), zero),
        (safe(b1 - a12, a11), one),
    ]
    inside_a = torch.where(det > 0, (b1 * a22 - b2 * a12) / det.clamp_min(1e-30), -one)
    inside_b = torch.where(det > 0, (a11 * b2 - a12 * b1) / det.clamp_min(1e-30), -one)
    ok = (inside_a >= 0) & (inside_a <= 1) & (inside_b >= 0) & (inside_b <= 1)
    best_a, best_b = candidates[0]
    best = q(best_a, best_b)
    for a, b in candidates[1:]:
        value = q(a, b)
        better = value < best
        best_a, best_b, best = torch.where(better, a, best_a), torch.where(better, b, best_b), torch.where(better, value, best)
    return torch.where(ok, inside_a, best_a), torch.where(ok, inside_b, best_b)


def keep_far(w):
    return (w[0], None if w[1] is None else torch.ones_like(w[1]))


def sq_error(pred, scan, cells):
    return (((pred - scan) * cells.to(pred.dtype)) ** 2).sum(dim=(2, 3), keepdim=True)


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far_flag=True):
    if PROBE.get("split"):
        return split_maps(fills, model, scan, mask, thinned, regimes, membrane, *PROBE["split"])
    n = scan.shape[0]
    fill, fill_thinned = check.checked_fills(fills, scan, mask, thinned, regimes, membrane)
    base, base_thinned = fills[0, :n], fills[0, n:]
    c, c_thinned = model[:n] - base, model[n:] - base_thinned
    w = regimes.weight(model[n:], fill_thinned, scan)
    if keep_far_flag:
        w = keep_far(w)
    shipped = regimes.apply(w, fill, model[:n], mask), regimes.apply(w, fill_thinned, model[n:], thinned)
    if not (PROBE.get("tp") or PROBE.get("sel") or PROBE.get("joint")):
        return shipped
    if PROBE.get("joint"):
        r = scan - fill_thinned
        near = joint_weights(model[n:] - fill_thinned, c_thinned, r, regimes.hidden)
        far = joint_weights(model[n:] - fill_thinned, c_thinned, r, regimes.outer) if regimes.outer is not None else None
        a = (near[0], None if far is None else far[0])
        b = (near[1], None if far is None else far[1])
        if keep_far_flag:
            a, b = keep_far(a), (b[0], None if b[1] is None else torch.zeros_like(b[1]))
        return (fill + regimes.at(a, mask) * (model[:n] - fill) + regimes.at(b, mask) * c,
                fill_thinned + regimes.at(a, thinned) * (model[n:] - fill_thinned) + regimes.at(b, thinned) * c_thinned)
    v = regimes.weight(fill_thinned + c_thinned, fill_thinned, scan)
    if keep_far_flag:
        v = keep_far(v)
    tp = fill + regimes.at(v, mask) * c, fill_thinned + regimes.at(v, thinned) * c_thinned
    if PROBE.get("tp"):
        return tp
    cells = regimes.hidden if regimes.outer is None else regimes.hidden | regimes.outer
    take = sq_error(tp[1], scan, cells) < sq_error(shipped[1], scan, cells)
    return torch.where(take, tp[0], shipped[0]), torch.where(take, tp[1], shipped[1])


def split_maps(fills, model, scan, mask, thinned, regimes, membrane, near_kind, far_kind):
    """The map as ``(1 - far) near + far far``: ``near_kind`` "A" the shipped near blend, "B" the
    fill plus the correction's near weight; ``far_kind`` "X" the net's map, "Y" the smooth fill
    (without the membrane) plus the correction, "Z" the checked fill plus the correction, "W"
    the net's map moved by the membrane's share (the checked fill less the smooth one), "H"
    halfway between "X" and "Y" (a fixed hedge between the two far fields, no judge)."""
    n = scan.shape[0]
    smooth = fills[:-1] if membrane else fills
    choice = check.best_fill(smooth[:, n:], scan, regimes.hidden)
    s_full, s_thin = check.pick(smooth[:, :n], choice), check.pick(smooth[:, n:], choice)
    fill, fill_thinned = check.checked_fills(fills, scan, mask, thinned, regimes, membrane)
    out = []
    for f, m, s_, obs, base in ((fill, model[:n], s_full, mask, fills[0, :n]), (fill_thinned, model[n:], s_thin, thinned, fills[0, n:])):
        c = m - base
        if near_kind == "A":
            w = regimes.weight(model[n:], fill_thinned, scan)[0]
            near = f + w * (m - f)
        else:
            v = regimes.weight(fill_thinned + (model[n:] - fills[0, n:]), fill_thinned, scan)[0]
            near = f + v * c
        far_map = {"X": m, "Y": s_ + c, "Z": f + c, "W": m + (f - s_), "H": 0.5 * (m + s_ + c)}[far_kind]
        share = regimes.far(obs).to(m.dtype) if regimes.outer is not None else torch.zeros_like(m)
        out.append((1 - share) * near + share * far_map)
    return tuple(out)


def settings_of(name: str) -> dict:
    out = {key: f"_{key}" in name for key in ("tp", "sel", "joint")}
    if m := re.search(r"_split([AB])([XYZWH])", name):
        out["split"] = (m[1], m[2])
    return out


if __name__ == "__main__":
    reconstructor.checked_maps = checked_maps
    run(settings_of, PROBE)
