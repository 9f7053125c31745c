"""Train the terrain reconstructor on an endless Warp-generated stream (Hydra entry point).

    python train.py                                   # a useful run on a 2-core CPU in ~5 minutes
    python train.py experiment=paper_octave3_noise10  # the paper's experiment, full schedule
    python train.py -m terrain=octave3,octave5 data.noise=0.05,0.10   # a sweep

The same as ``warp-terrain train`` for an installed wheel; nothing else happens here.
"""

from warp_terrain.cli.train import main

if __name__ == "__main__":
    main()
