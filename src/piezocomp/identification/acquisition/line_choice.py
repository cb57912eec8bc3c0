"""Choice of the identification line from an overview image (Section V, step 1).

The line must cross more particles than the degree of the loop polynomial ``f_a`` (eq 23
gives one equation per particle seen on both traces) and span the working area. Each row
(axis ``"x"``) or column (axis ``"y"``) of the overview is a candidate: its particles are the
peaks found on its forward trace that pair up with a peak of its backward trace. The
candidate with the most paired particles wins (ties: the one whose particles spread widest
along the line); a candidate with no more particles than the degree is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar, readonly
from piezocomp.identification.acquisition.peaks import find_peaks, pair_peaks
from piezocomp.instrument import ScanImage

__all__ = ["LineChoice", "choose_line", "count_line_particles"]


@dataclass(frozen=True)
class LineChoice:
    """The chosen line.

    Attributes
    ----------
    axis : str
        ``"x"`` (a row, fast axis x) or ``"y"`` (a column).
    index : int
        Row (axis x) or column (axis y) of the overview.
    slow_nm : float
        Command of the other axis on the line (nm).
    n_particles : int
        Paired particles on the line.
    positions_nm : ndarray
        Forward-trace positions of those particles along the line (nm of command).
    counts : ndarray of int
        Paired particles of every candidate line.
    """

    axis: str
    index: int
    slow_nm: float
    n_particles: int
    positions_nm: NDArray[np.float64]
    counts: NDArray[np.int64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "positions_nm", readonly(self.positions_nm))
        c = np.array(self.counts, dtype=np.int64)
        c.setflags(write=False)
        object.__setattr__(self, "counts", c)


def count_line_particles(
    position_nm: NDArray[np.float64],
    forward_nm: NDArray[np.float64],
    backward_nm: NDArray[np.float64],
    *,
    min_prominence_nm: float,
    max_shift_nm: float,
) -> NDArray[np.float64]:
    """Forward positions of the peaks of one line that pair with a backward peak (nm)."""
    sep = 2.0 * abs(float(position_nm[1] - position_nm[0]))
    pf = find_peaks(
        position_nm, forward_nm, min_prominence_nm=min_prominence_nm, min_separation_nm=sep
    )
    pb = find_peaks(
        position_nm, backward_nm, min_prominence_nm=min_prominence_nm, min_separation_nm=sep
    )
    i_f, _ = pair_peaks(pf.position_nm, pb.position_nm, max_shift_nm=max_shift_nm)
    return np.asarray(pf.position_nm[i_f], dtype=float)


def choose_line(
    image: ScanImage,
    *,
    degree: int = 5,
    axis: str = "x",
    min_prominence_nm: float = 3.0,
    max_shift_nm: float | None = None,
    min_coverage: float = 0.5,
) -> LineChoice:
    """Choose the line of the overview that crosses the most particles.

    Parameters
    ----------
    image : ScanImage
        Overview of the working area (its fast-axis extent is the span of the line).
    degree : int
        Degree of the loop polynomial ``f_a``; the line needs more than ``degree`` particles.
    axis : {"x", "y"}
        ``"x"``: rows (lines along x); ``"y"``: columns (lines along y; the "backward" trace of
        a column is that of the backward image).
    min_prominence_nm : float
        Smallest particle prominence (nm).
    max_shift_nm : float, optional
        Largest forward-backward shift of one particle (nm); default 10 % of the line length
        (the loop width of a scanner with large hysteresis).
    min_coverage : float
        The particles must spread over at least this fraction of the line (first to last),
        so that the loop is constrained over the whole working span.

    Returns
    -------
    LineChoice

    Raises
    ------
    ValueError
        If no line crosses more than ``degree`` particles spread over ``min_coverage`` of
        it; the message gives the best count found and the rule.
    """
    if not isinstance(image, ScanImage):
        raise TypeError(f"image must be a ScanImage. Got {type(image).__name__}.")
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    if isinstance(degree, bool) or int(degree) != degree or degree < 1:
        raise ValueError(f"degree must be an integer >= 1. Got {degree!r}.")
    prom = check_finite_scalar("min_prominence_nm", min_prominence_nm)
    cover = check_finite_scalar("min_coverage", min_coverage)
    if axis == "x":
        pos, slow = image.x_nm, image.y_nm
        fwd, bwd = image.forward_nm, image.backward_nm
    else:
        pos, slow = image.y_nm, image.x_nm
        fwd, bwd = image.forward_nm.T, image.backward_nm.T
    length = float(abs(pos[-1] - pos[0]))
    shift = (
        0.1 * length if max_shift_nm is None else check_finite_scalar("max_shift_nm", max_shift_nm)
    )
    found = [
        count_line_particles(pos, fwd[i], bwd[i], min_prominence_nm=prom, max_shift_nm=shift)
        for i in range(fwd.shape[0])
    ]
    counts = np.array([p.size for p in found], dtype=np.int64)
    spread = np.array([float(np.ptp(p)) / length if p.size > 1 else 0.0 for p in found])
    eligible = (counts > degree) & (spread >= cover)
    if not eligible.any():
        best = int(np.argmax(counts))
        raise ValueError(
            f"no {'row' if axis == 'x' else 'column'} of the overview crosses more than "
            f"degree = {degree} particles spread over {cover:.0%} of the line (eq 23 needs more "
            f"equations than the degree of f_a): the best, index {best} at "
            f"{slow[best]:.1f} nm, crosses {counts[best]} (spread {spread[best]:.0%}). Image "
            "another area, lower the degree or the prominence threshold."
        )
    key = np.where(eligible, counts + 0.5 * spread, -1.0)
    i = int(np.argmax(key))
    return LineChoice(axis, i, float(slow[i]), int(counts[i]), found[i], counts)
