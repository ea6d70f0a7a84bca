"""Training curves: the two-panel figure the training loops draw (matplotlib Agg, no display)."""

from __future__ import annotations

from pathlib import Path

from m2h_ros.core.plotting import agg_pyplot


def two_panels(figsize: tuple[float, float] = (11, 4)):
    """(figure, (left axes, right axes)) on the Agg backend."""
    return agg_pyplot().subplots(1, 2, figsize=figsize)


def save_panels(fig, axes, path: Path) -> Path:
    """Grid and legend on every panel, then the PNG; the figure is closed."""
    plt = agg_pyplot()
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
