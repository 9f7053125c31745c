"""The Hydra configs, installed as the package ``warp_terrain.conf`` (YAML files only)."""
