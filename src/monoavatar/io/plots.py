"""Line and bar plots written as PNG (matplotlib, headless), for training curves and the
benchmark's figures."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from monoavatar.core.files import atomic_path

__all__ = ["line_plot"]


def line_plot(path: str | Path, series: dict[str, tuple[Sequence[float], Sequence[float]]],
              xlabel: str, ylabel: str, title: str = "", logy: bool = False,
              connect: bool = True) -> Path:
    """Write one chart with a line (with markers; markers alone when not ``connect``) per
    ``series`` label → (x, y) to ``path`` (PNG, about 640 x 400 pixels), atomically. Returns
    the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=100)
    try:
        for label, (x, y) in series.items():
            ax.plot(np.asarray(x, float), np.asarray(y, float), marker="o",
                    markersize=3 if connect else 6, linestyle="-" if connect else "none",
                    label=label)  # fmt: skip
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        if title:
            ax.set_title(title)
        if logy:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
        if len(series) > 1:
            ax.legend()
        fig.tight_layout()
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(out) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return out
