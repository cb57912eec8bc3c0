"""Figures of the virtual AFM: topography images."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from piezocomp.plotting import new_figure, save_figure

__all__ = ["plot_topography"]


def plot_topography(
    path: str | os.PathLike[str],
    height_nm: NDArray[np.float64],
    extent_nm: Sequence[float],
    title: str,
) -> None:
    """Write one topography image (nm colour scale, command axes) as PNG."""
    fig, ax = new_figure(figsize=(5.5, 4.6), dpi=110)
    im = ax.imshow(
        height_nm, origin="lower", extent=list(extent_nm), cmap="afmhot", interpolation="nearest"
    )
    ax.set_xlabel("x command (nm)")
    ax.set_ylabel("y command (nm)")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label="height (nm)")
    save_figure(fig, path, dpi=110)
