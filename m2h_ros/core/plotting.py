"""matplotlib for the project's figures: files only, no display."""

from __future__ import annotations


def agg_pyplot():
    """``matplotlib.pyplot`` on the Agg backend, imported when a figure is drawn (so importing a module that
    can plot costs nothing and needs no display)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt
