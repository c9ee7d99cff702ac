"""recon: models built from captured images. ``poses/`` (COLMAP, ChArUco, alignment and scoring),
``slab/`` (light slabs assembled or rebinned from captures; rendered by render.lightfield),
``nerf/`` (radiance fields in PyTorch). Imports render, never rig."""
