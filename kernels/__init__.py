"""Warp kernels of warp-terrain: terrain synthesis, LIDAR ray casting and ground projection.

Kernels only (``@wp.kernel`` / ``@wp.func`` / ``@wp.struct``): no torch and no orchestration.
The Python-side launches live in ``warp_terrain.sim``. One idea per file:

- ``rng``          per-sample seeds and independent random streams
- ``heightfield``  the terrain surface (two triangles per cell) and its max-height tiles
- ``noise``        fBm Perlin heightfields on ``wp.noise``
- ``obstacles``    sampling and stamping cylinders, boxes, rocks, pits and ditches
- ``clutter``      bushes, grass and tree crowns: the canopy layer above the ground
- ``raycast``      casting LIDAR rays against heightfields (where the rays are cast)
- ``projection``   binning points into elevation maps, image noise
- ``ground_truth`` the cell-averaged true elevation map
- ``frames``       the dihedral (flip / 90-degree) augmentation of the sensor frame
"""
