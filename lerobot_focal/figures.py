"""Writing the PNGs that benchmarks and demos show beside their tables."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # matplotlib loads in the plotting functions, never at import of a command
    from matplotlib.figure import Figure


def save_png(fig: Figure, path: Path | str, dpi: int = 100) -> None:
    """Lay out, write and close: an open figure per call keeps its memory for the life of a long grid run."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
