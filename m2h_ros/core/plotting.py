"""matplotlib for the project's figures: files only, no display."""

from __future__ import annotations

from pathlib import Path


def agg_pyplot():
    """``matplotlib.pyplot`` on the Agg backend, imported when a figure is drawn (so importing a module that
    can plot costs nothing and needs no display)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def save_line_plot(fig, ax, path: str | Path) -> Path:
    """Finish a one-axes line plot (light grid, small legend) and write it to ``path`` at 120 dpi."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    agg_pyplot().close(fig)
    return Path(path)
