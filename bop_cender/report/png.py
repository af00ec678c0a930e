"""The project's figures (scene figures, error plots, comparison charts) made and written one way.

matplotlib is imported where a figure is made, not when the package is (the scorer and the runner need none), on the
Agg backend (no display: CI, clusters); a figure is written atomically (a reader never sees half a PNG) and closed
even when writing fails (pyplot keeps every open figure alive).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bop_cender.data.bop_io import atomic_path


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, path: Path, dpi: int) -> Path:
    """Lay ``fig`` out tightly, write it to ``path`` (PNG, atomically, its folder made) and close it; ``path``."""
    plt = pyplot()
    try:
        fig.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return path
