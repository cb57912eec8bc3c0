"""Image registration: how far the content of one scan lies from another's, to a fraction of
a pixel.

The paper measures positioning errors as the translation between two images of the same
area, found by cross-correlation (Sec. V, after its ref. [4]); drift compensation measures
drift the same way. :func:`image_displacement` levels both images
(:func:`piezocomp.imaging.features.level`), tapers them with a Hann window
(:func:`skimage.filters.window`: features cut by the border weigh little, and the overlap
of the images' backgrounds no longer pulls the match towards no shift) and registers them
by cross-correlation with :func:`skimage.registration.phase_cross_correlation`
(``normalization=None``: plain cross-correlation, which weighs the particles by their
heights and stays robust on sparse images; upsampled for sub-pixel precision). The taper
weighs a feature that moved off-centre less, which alone would bias the shift towards zero
(a third of it for one particle in a small window); so the second image is shifted back by
the shift found (:func:`scipy.ndimage.shift`) and registered again, a few times, until the
remainder is what the taper cannot bias. On sparse images of a scanner that distorts each
scan differently, the match follows the particles: it measures the shift where they are,
not the mean over the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi
from skimage.filters import window
from skimage.registration import phase_cross_correlation

from piezocomp._validation import check_finite_scalar
from piezocomp.imaging.features import level, trace_heights
from piezocomp.instrument import ScanImage

__all__ = ["Displacement", "image_displacement"]

MIN_FEATURE_NM = 1.0
"""An image whose levelled heights span less than this holds nothing to register."""

REFINE_ROUNDS = 4
"""Most registrations of the second image shifted back by the shift found so far."""

MAX_SHIFT_FRACTION = 1.0 / 3.0
"""A match farther than this fraction of the image's side is refused: the two images then
share too little to say which of their features are the same."""


@dataclass(frozen=True)
class Displacement:
    """Translation between two images.

    Attributes
    ----------
    content_shift_nm : (float, float)
        ``(dx, dy)`` by which the features of the second image lie from where they are in
        the first, nm, in the images' frame.
    error : float
        scikit-image's translation-invariant normalised RMS error of the match (0: a
        perfect match; near 1: nothing matches).
    """

    content_shift_nm: tuple[float, float]
    error: float

    @property
    def tip_offset_nm(self) -> tuple[float, float]:
        """How far the tip was from where it was the first time when it scanned the second
        image (the negative of the content's shift)."""
        return (-self.content_shift_nm[0], -self.content_shift_nm[1])

    @property
    def magnitude_nm(self) -> float:
        """Length of the shift, nm."""
        return math.hypot(*self.content_shift_nm)


def image_displacement(
    first: ScanImage,
    second: ScanImage,
    *,
    trace: str = "forward",
    upsample: int = 100,
    max_shift_fraction: float = MAX_SHIFT_FRACTION,
    min_feature_nm: float = MIN_FEATURE_NM,
) -> Displacement:
    """Translation of ``second``'s content relative to ``first``'s (same grid).

    Parameters
    ----------
    first, second : ScanImage
        Two images over the same grid (same pixel positions).
    trace : {"forward", "backward", "mean"}
        Trace registered (``"mean"``: both traces averaged).
    upsample : int
        Upsampling factor of the correlation peak: the shift is resolved to
        ``1 / upsample`` pixel.
    max_shift_fraction : float
        Largest plausible shift, as a fraction of the image's side (sparse images that share
        few features can match one particle with another far away).
    min_feature_nm : float
        An image whose levelled heights span less than this is flat: nothing to register
        (default :data:`MIN_FEATURE_NM`, for particles; an atomic-resolution image's
        corrugation is a tenth of a nanometre).

    Raises
    ------
    ValueError
        If the images' grids differ, an image holds no features (flat within
        :data:`MIN_FEATURE_NM`), or the match lies farther than ``max_shift_fraction`` of
        the image: no trustworthy displacement.
    """
    a, b = (level(trace_heights(img, trace)) for img in (first, second))
    if isinstance(upsample, bool) or not isinstance(upsample, int) or upsample < 1:
        raise ValueError(f"upsample must be an integer >= 1. Got {upsample!r}.")
    if (
        first.x_nm.shape != second.x_nm.shape
        or first.y_nm.shape != second.y_nm.shape
        or not np.allclose(first.x_nm, second.x_nm)
        or not np.allclose(first.y_nm, second.y_nm)
    ):
        raise ValueError("the two images must be taken over the same grid of pixels.")
    for name, z in (("first", a), ("second", b)):
        if float(np.ptp(z)) < min_feature_nm:
            raise ValueError(
                f"the {name} image is flat (heights span {float(np.ptp(z)):.3g} nm < "
                f"{min_feature_nm:g} nm): nothing to register."
            )
    w = window("hann", a.shape)
    shift = np.zeros(2)
    err = 0.0
    for _ in range(REFINE_ROUNDS):
        moved = b if not shift.any() else ndi.shift(b, shift, order=3, mode="nearest")
        step, err, _ = phase_cross_correlation(
            a * w, moved * w, upsample_factor=upsample, normalization=None
        )
        shift = shift + np.asarray(step, dtype=float)
        if np.max(np.abs(step)) < 0.5 / upsample:
            break
    px = float(np.mean(np.diff(first.x_nm))) if first.x_nm.size > 1 else 1.0
    py = float(np.mean(np.diff(first.y_nm))) if first.y_nm.size > 1 else 1.0
    # shift (rows, cols) registers ``second`` onto ``first``: its content lies at -shift
    dx = check_finite_scalar("shift", -float(shift[1]) * px)
    dy = check_finite_scalar("shift", -float(shift[0]) * py)
    frac = check_finite_scalar("max_shift_fraction", max_shift_fraction)
    if max(abs(float(shift[0])) / a.shape[0], abs(float(shift[1])) / a.shape[1]) > frac:
        raise ValueError(
            f"the best match lies ({dx:.1f}, {dy:.1f}) nm away, more than {frac:.2f} of the "
            "image: the images share too little to register."
        )
    return Displacement((dx, dy), float(err))
