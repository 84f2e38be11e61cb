"""Structure from motion: camera models, reprojection and bundle adjustment."""
