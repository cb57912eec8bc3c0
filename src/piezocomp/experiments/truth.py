"""True errors of an experiment, from a simulator's ground truth (scoring only).

An experiment decides everything from what the instrument returns; when it runs on the
virtual AFM it also reports its errors against the ground truth
(:class:`~piezocomp.virtual_afm.GroundTruth`), read here through the time stamps of the records and
images it produced. Nothing read here feeds back into what the experiment does.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp.instrument import ScanImage

__all__ = ["Truth", "true_displacement", "true_image_position"]


class Truth(Protocol):
    """What scoring reads of a simulator: true tip positions at sample times, and the true
    particles (an object with ``xy_nm``, (n, 2) centres, sample frame)."""

    def positions_at(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """True tip positions (sample frame, nm) at sample times ``t_s``."""
        ...

    def particles(self) -> Any:
        """True particles now."""
        ...


def true_image_position(truth: Truth, image: ScanImage) -> NDArray[np.float64]:
    """Mean true tip position over every pixel of an image (both traces), nm."""
    fwd, bwd = image.pixel_times_s()
    return np.asarray(truth.positions_at(np.stack([fwd, bwd])).reshape(-1, 2).mean(axis=0))


def true_displacement(truth: Truth, first: ScanImage, second: ScanImage) -> float:
    """How far, truly, the second image was scanned from the first (nm): the distance
    between their mean true tip positions, which is what image registration measures."""
    d = true_image_position(truth, second) - true_image_position(truth, first)
    return float(np.hypot(*d))
