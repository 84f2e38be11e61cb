"""Pose-graph and bundle-adjustment files: g2o, TORO and BAL."""
