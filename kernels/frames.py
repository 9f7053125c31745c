"""Dihedral augmentation of the sensor frame: 90-degree rotations about z and a mirror.

Transform ``d`` in 0..7 first mirrors y when ``d >= 4``, then rotates by ``(d % 4) * 90`` degrees
about z. Applied to point clouds it turns the elevation map exactly as ``torch.rot90`` /
``torch.flip`` would, without resampling.
"""

import warp as wp

from .rng import STREAM_AUGMENT, stream_state

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator


@wp.func
def dihedral_apply(d: int, p: wp.vec2) -> wp.vec2:
    x = p[0]
    y = p[1]
    if d >= 4:
        y = -y
    k = d % 4
    if k == 1:
        return wp.vec2(-y, x)
    if k == 2:
        return wp.vec2(-x, -y)
    if k == 3:
        return wp.vec2(y, -x)
    return wp.vec2(x, y)


@wp.func
def dihedral_invert(d: int, p: wp.vec2) -> wp.vec2:
    k = d % 4
    x = p[0]
    y = p[1]
    # undo the rotation
    if k == 1:
        x = p[1]
        y = -p[0]
    elif k == 2:
        x = -p[0]
        y = -p[1]
    elif k == 3:
        x = -p[1]
        y = p[0]
    if d >= 4:
        y = -y
    return wp.vec2(x, y)


@wp.func
def sample_transform(seed: int, b: int, augment: int) -> int:
    """Dihedral transform of sample ``b`` (0, the identity, when ``augment`` is 0)."""
    if augment == 0:
        return 0
    state = stream_state(seed, b, STREAM_AUGMENT, 0)
    return wp.randi(state, 0, 8)
