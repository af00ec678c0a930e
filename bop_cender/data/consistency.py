"""Pose-consistency checks between files that store the same pose twice.

Real files are rounded (T-LESS stores t to 0.01 mm and R to 6 digits), so small residuals are
normal; a frame mix-up (c2w read as w2c) is off by hundreds of mm. Hence two thresholds:
warn above :data:`WARN_MM` / :data:`WARN_RAD`, fail above :data:`FAIL_MM` / :data:`FAIL_RAD`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bop_cender.errors import DatasetError, DatasetWarning
from bop_cender.geometry.poses import pose_residual

WARN_MM = 0.1
WARN_RAD = 1e-4
FAIL_MM = 5.0
FAIL_RAD = 0.01


@dataclass
class ResidualTracker:
    """Collects the largest residual between pose pairs; fails at once on a gross mismatch.

    Attributes:
        max_mm: largest translation residual seen (mm).
        max_rad: largest rotation residual seen (rad).
        worst: where the largest residual (by mm, then rad) was seen.
        count: pose pairs compared.
    """

    max_mm: float = 0.0
    max_rad: float = 0.0
    worst: str = ""
    count: int = 0
    _warned: set = field(default_factory=set)

    def check(self, T_expected: np.ndarray, T_stored: np.ndarray, file: Path | str, where: str, relation: str) -> None:
        """Compare two transforms that should be equal.

        Args:
            T_expected: the transform derived from other files (e.g. ``T_cam_world @ T_world_model``).
            T_stored: the transform stored in ``file`` at ``where``.
            relation: the identity being checked, for the message.

        Raises:
            DatasetError: residual above 5 mm or 0.01 rad.
        """
        dt, dr = pose_residual(T_expected, T_stored)
        self.count += 1
        if dt > self.max_mm or dr > self.max_rad:
            if dt >= self.max_mm:
                self.worst = f"{file}: {where}"
            self.max_mm = max(self.max_mm, dt)
            self.max_rad = max(self.max_rad, dr)
        if dt > FAIL_MM or dr > FAIL_RAD:
            raise DatasetError(
                f"pose inconsistent with {relation}: off by {dt:.3f} mm / {dr:.4f} rad"
                f" (expected <= {FAIL_MM} mm / {FAIL_RAD} rad; a frame mix-up such as c2w read as w2c?)",
                file=file,
                field=where,
            )

    def report(self, what: str) -> None:
        """Warn once (per ``what``) if the largest residual is above the warning thresholds."""
        if (self.max_mm > WARN_MM or self.max_rad > WARN_RAD) and what not in self._warned:
            self._warned.add(what)
            warnings.warn(
                f"{what}: poses agree only to {self.max_mm:.3f} mm / {self.max_rad:.2e} rad"
                f" (largest at {self.worst}); tolerated up to {FAIL_MM} mm / {FAIL_RAD} rad",
                DatasetWarning,
                stacklevel=2,
            )
