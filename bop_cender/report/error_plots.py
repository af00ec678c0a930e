"""The report's plots: how the evaluated rows' MSSD and MSPD errors fall against the protocol's thresholds.

One PNG per error, a cumulative curve (the fraction of evaluated rows with an error at most x) with the thresholds as
vertical lines: where the curve crosses a line is the share of rows that can be hits at that threshold, which is what
a recall is made of (a hit also needs its GT instance not taken by a better-scored row). Errors beyond the plotted
range (the loosest threshold x 1.5, and ``inf`` where the scorer stopped computing) are counted in the title, not
drawn off the chart.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bop_cender.report.png import pyplot, save_png

#: The plotted range: up to this multiple of the loosest threshold.
RANGE = 1.5
#: Axis label and unit of each error.
LABELS = {"mssd": "MSSD / object diameter", "mspd": "MSPD (px, image 640 wide)"}


def error_plot(name: str, errors: np.ndarray, thresholds: np.ndarray, path: Path) -> Path:
    """Write the cumulative distribution of ``errors (N,)`` against ``thresholds (K,)`` to ``path`` (PNG, atomically).

    Returns ``path``; a file of no evaluated row gets an empty chart that says so (the page still shows it)."""
    plt = pyplot()

    errors = np.asarray(errors, dtype=np.float64)
    top = float(np.max(thresholds)) * RANGE
    shown = np.sort(errors[np.isfinite(errors) & (errors <= top)])
    beyond = len(errors) - len(shown)
    fig, ax = plt.subplots(figsize=(5.0, 3.0))
    if len(errors):
        fraction = np.arange(1, len(shown) + 1) / len(errors)
        ax.step(np.concatenate([[0.0], shown, [top]]), np.concatenate([[0.0], fraction, fraction[-1:] if len(shown) else [0.0]]),
                where="post", color="tab:blue", lw=1.5)  # fmt: skip
    else:
        ax.text(0.5, 0.5, "no evaluated row", ha="center", va="center", transform=ax.transAxes)
    for k, th in enumerate(thresholds):
        ax.axvline(
            float(th), color="tab:red" if k == 0 else "0.6", lw=1.0 if k == 0 else 0.6, ls="-" if k == 0 else "--"
        )
    ax.set_xlim(0.0, top)
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel(LABELS.get(name, name), fontsize=8)
    ax.set_ylabel("fraction of evaluated rows", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(
        f"{name.upper()}: {len(errors)} evaluated rows, {beyond} beyond {top:g}; thresholds dashed, strictest red",
        fontsize=8,
    )
    return save_png(fig, path, dpi=100)


def share_within(errors: np.ndarray, threshold: float) -> float | None:
    """The fraction of ``errors`` under ``threshold`` (the protocol's ``e < th``), None without any error: the figure
    the page writes beside each plot, so that a reader need not read it off the curve."""
    errors = np.asarray(errors, dtype=np.float64)
    return float(np.mean(errors < threshold)) if len(errors) else None
