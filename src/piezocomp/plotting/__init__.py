"""Figures. The only place that imports matplotlib (always with the Agg backend).

One module per topic (``plotting.identification``, ``plotting.loop`` ...), each with
functions ``plot_x(result, path)`` that write a PNG atomically.

May import the core and the result types of :mod:`piezocomp.identification`,
:mod:`piezocomp.sensor` and :mod:`piezocomp.imaging`, and read any result object it is handed
(the experiments' results typed only: :mod:`piezocomp.experiments` imports this package);
imported only by the command line and the experiments' report.
"""

from __future__ import annotations

import io
import os
from typing import Any

from piezocomp._atomic import atomic_write_bytes

__all__ = ["legend_above", "legend_right", "new_figure", "save_figure"]


def new_figure(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
    """``plt.subplots`` on the Agg backend (never opens a window)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def legend_above(ax: Any, ncol: int = 4, **kwargs: Any) -> Any:
    """A legend in one row above ``ax``, clear of its data (for axes without a title; the
    saved figure grows to hold it)."""
    return ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=ncol, borderaxespad=0.0,
                     fontsize=7, frameon=False, **kwargs)  # fmt: skip


def legend_right(ax: Any, **kwargs: Any) -> Any:
    """A legend right of ``ax``, clear of its data (the saved figure grows to hold it)."""
    return ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
                     fontsize=7, **kwargs)  # fmt: skip


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 120) -> None:
    """Write ``fig`` as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
