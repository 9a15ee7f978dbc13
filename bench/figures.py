"""Matplotlib figures without pyplot (no global state, no display): a figure on the Agg canvas, and its PNG bytes
with no software stamp, so the same figure gives the same bytes. matplotlib is imported on first use."""

from __future__ import annotations

import io


def agg_figure(width: float, height: float):
    """A constrained-layout figure of `width` × `height` inches on its own Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig) -> bytes:
    """The figure as PNG at 100 dpi, without the Software metadata."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, metadata={"Software": None})
    return buffer.getvalue()
