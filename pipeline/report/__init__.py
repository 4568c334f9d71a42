"""Figures and tables. Functions return matplotlib figures and never show them.

Figures are plain :class:`matplotlib.figure.Figure` objects with an Agg canvas of their own
(:func:`subplots`), so nothing here touches pyplot's state or the user's matplotlib backend.
"""

from __future__ import annotations


def subplots(*args, figsize=None, layout=None, **kwargs):
    """Like ``pyplot.subplots``, but a standalone figure drawn by Agg: (fig, axes)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout=layout)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(*args, **kwargs)
