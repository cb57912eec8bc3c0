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

__all__ = ["new_figure", "save_figure"]


def new_figure(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
    """``plt.subplots`` on the Agg backend (never opens a window)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 120) -> None:
    """Write ``fig`` as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
