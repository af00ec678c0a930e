"""The seam to the official BOP toolkit's conventions (naming, targets, optional cross-check)."""
