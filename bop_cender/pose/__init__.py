"""Stage 3: render-and-compare pose estimation (cost function, optimisation)."""
