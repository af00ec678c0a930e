"""Stage 1 of CenDerNet: per-view center and curvature heatmaps (GT targets, the oracle, the network)."""
