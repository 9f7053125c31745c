"""Per-sample seeds and independent random streams.

A batch is generated from one integer seed. Sample ``b`` of that batch gets its own seed
``sample_seed(seed, b)`` so that a sample does not depend on the batch size, and each use of
randomness (terrain, obstacles, rays, image noise, augmentation) draws from its own stream.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: nothing differentiates through the simulator

STREAM_TERRAIN = wp.constant(0x1B873593)
STREAM_OBSTACLES = wp.constant(0x2545F491)
STREAM_RAYS = wp.constant(0x61C88647)
STREAM_IMAGE_NOISE = wp.constant(0x7FEB352D)
STREAM_AUGMENT = wp.constant(0x165667B1)


@wp.func
def sample_seed(seed: int, sample: int) -> int:
    """Seed of sample ``sample`` in a batch generated with ``seed``."""
    state = wp.rand_init(seed, sample)
    return wp.randi(state)


@wp.func
def stream_state(seed: int, sample: int, stream: int, offset: int) -> wp.uint32:
    """RNG state for one use (``stream``) of one sample, at ``offset`` within that use."""
    return wp.rand_init(sample_seed(seed, sample) ^ stream, offset)
