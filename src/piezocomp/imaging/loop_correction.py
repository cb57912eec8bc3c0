"""Section IV on a real image: fit the symmetric loop from trace/retrace features and undo it.

On every line of a raster image the fast-axis command runs from ``u_min`` to ``u_max`` (forward
trace, ascending branch ``f_a``) and back (backward trace, descending branch ``f_d``). Features seen
on both traces (particle tops; for gratings also the steepest rising and falling edges and the
valleys) are found with sub-sample precision, paired, and the pairs of all lines fit one
:class:`~piezocomp.identification.loop.symmetric.SymmetricLoop` (eq (23)). Each trace is then
re-sampled on a uniform grid of true position: the forward pixel at command ``u`` sits at ``y =
f_a(u)``, the backward one at ``y = f_d(u)`` (eq (22)).

The trace/retrace mismatch before and after (:mod:`.mismatch`) says how well it worked.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.identification.acquisition.peaks import find_peaks, pair_peaks
from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.imaging.mismatch import MismatchStats, detrend_rows, line_shifts_nm, mismatch_stats
from piezocomp.io.afm_scan import AfmScan

__all__ = [
    "FeaturePairs",
    "LoopCorrection",
    "correct_scan",
    "scan_feature_pairs",
]


# ---------------------------------------------------------------------------------------------
# Features and pairs
# ---------------------------------------------------------------------------------------------
def _noise_sigma(rows: NDArray[np.float64]) -> float:
    """Robust white-noise level of the rows (MAD of first differences / sqrt 2)."""
    d = np.diff(rows, axis=1).ravel()
    mad = float(np.median(np.abs(d - np.median(d))))
    return 1.4826 * mad / np.sqrt(2.0)


def _feature_signals(img: NDArray[np.float64], smooth_px: int) -> dict[str, NDArray[np.float64]]:
    """Signals whose peaks are features: heights, -heights, +slope and -slope per row."""
    win = max(5, 2 * (smooth_px // 2) + 1)
    sm = scipy.signal.savgol_filter(img, win, 2, axis=1)
    slope = scipy.signal.savgol_filter(img, win, 2, deriv=1, axis=1)
    return {"top": sm, "valley": -sm, "rise": slope, "fall": -slope}


@dataclass(frozen=True)
class FeaturePairs:
    """Features seen on both traces, gathered over lines.

    Attributes
    ----------
    u_ascending_nm, u_descending_nm : ndarray, shape (n,)
        Command at which each feature is seen on the forward and backward trace (nm).
    line : ndarray of int, shape (n,)
        Line index of each pair.
    kind : ndarray of str, shape (n,)
        ``"top"``, ``"valley"``, ``"rise"`` or ``"fall"``.
    """

    u_ascending_nm: NDArray[np.float64]
    u_descending_nm: NDArray[np.float64]
    line: NDArray[np.intp]
    kind: NDArray[np.str_]

    def __len__(self) -> int:
        return int(self.u_ascending_nm.size)

    def select(self, mask: NDArray[np.bool_]) -> FeaturePairs:
        """The pairs where ``mask`` is true."""
        return FeaturePairs(
            self.u_ascending_nm[mask], self.u_descending_nm[mask], self.line[mask], self.kind[mask]
        )


def scan_feature_pairs(
    forward_nm: ArrayLike,
    backward_nm: ArrayLike,
    u_nm: ArrayLike,
    *,
    typical_shift_nm: float,
    tolerance_nm: float,
    min_snr: float = 8.0,
    smooth_px: int = 5,
) -> FeaturePairs:
    """Find and pair features line by line (:func:`find_peaks`, :func:`pair_peaks`).

    Parameters
    ----------
    forward_nm, backward_nm : array_like, shape (ny, nx)
        The two traces, backward stored left to right.
    u_nm : array_like, shape (nx,)
        Fast-axis command of each column (nm).
    typical_shift_nm : float
        Expected ``forward - backward`` shift (nm), e.g. the median of :func:`line_shifts_nm`.
    tolerance_nm : float
        Largest deviation of a pair's shift from the typical shift (nm).
    min_snr : float, optional
        A feature's prominence must exceed ``min_snr`` times the noise of its signal.
    smooth_px : int, optional
        Savitzky-Golay window (pixels) smoothing the rows before taking peaks and slopes.
    """
    f = detrend_rows(as_finite_array("forward_nm", forward_nm, ndim=2))
    b = detrend_rows(as_finite_array("backward_nm", backward_nm, ndim=2))
    u = np.asarray(u_nm, dtype=float)
    step = float(np.mean(np.abs(np.diff(u))))
    sig_f = _feature_signals(f, smooth_px)
    sig_b = _feature_signals(b, smooth_px)
    # Forward positions minus the typical shift: the pairing gates around zero.
    max_shift = abs(typical_shift_nm) + tolerance_nm
    ua: list[NDArray[np.float64]] = []
    ud: list[NDArray[np.float64]] = []
    lines: list[NDArray[np.intp]] = []
    kinds: list[NDArray[np.str_]] = []
    for kind in sig_f:
        sf, sb = sig_f[kind], sig_b[kind]
        noise = max(_noise_sigma(np.concatenate([sf, sb], axis=0)), 1e-12)
        threshold = min_snr * noise
        sep = 2.0 * max(tolerance_nm, step)
        for i in range(f.shape[0]):
            pf = find_peaks(u, sf[i], min_prominence_nm=threshold, min_separation_nm=sep)
            pb = find_peaks(u, sb[i], min_prominence_nm=threshold, min_separation_nm=sep)
            if len(pf) == 0 or len(pb) == 0:
                continue
            jf, jb = pair_peaks(
                pf.position_nm - typical_shift_nm,
                pb.position_nm,
                max_shift_nm=max(tolerance_nm, 1e-9),
                tolerance_nm=tolerance_nm,
            )
            if jf.size == 0:
                continue
            a = pf.position_nm[jf]
            d = pb.position_nm[jb]
            within = np.abs(a - d) <= max_shift + 1e-9
            ua.append(a[within])
            ud.append(d[within])
            lines.append(np.full(int(within.sum()), i, dtype=np.intp))
            kinds.append(np.full(int(within.sum()), kind))
    if not ua:
        return FeaturePairs(np.empty(0), np.empty(0), np.empty(0, np.intp), np.empty(0, "<U6"))
    return FeaturePairs(
        np.concatenate(ua), np.concatenate(ud), np.concatenate(lines), np.concatenate(kinds)
    )


# ---------------------------------------------------------------------------------------------
# Correction
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoopCorrection:
    """Result of :func:`correct_scan`.

    Attributes
    ----------
    loop : SymmetricLoop
        The fitted loop of the fast axis (eqs (21)-(23)).
    u_nm : ndarray, shape (nx,)
        Command of each column of the raw images (nm).
    position_nm : ndarray, shape (nx,)
        Uniform true-position grid of the corrected images (nm).
    forward_nm, backward_nm : ndarray, shape (ny, nx)
        Corrected forward and backward images on ``position_nm``.
    pairs : FeaturePairs
        The feature pairs used in the final fit.
    before, after : MismatchStats
        Trace/retrace mismatch of the raw and of the corrected images.
    smoothing : float
        Curvature penalty of the final fit (:meth:`SymmetricLoop.from_peaks`).
    pair_scatter_nm : float
        Robust standard deviation of the pair residuals under the stiff first fit (nm).
    pair_rms_nm : float
        RMS of ``f_a(u_a) - f_d(u_d)`` over the kept pairs under the final loop (nm).
    pairs_rejected : int
        Pairs dropped as outliers.
    after_heldout : MismatchStats or None
        Mismatch of the odd lines corrected by a loop fitted on the pairs of the even lines
        only (a check that the loop is not fitted to each line's own noise).
    """

    loop: SymmetricLoop
    u_nm: NDArray[np.float64]
    position_nm: NDArray[np.float64]
    forward_nm: NDArray[np.float64]
    backward_nm: NDArray[np.float64]
    pairs: FeaturePairs
    before: MismatchStats
    after: MismatchStats
    smoothing: float = 0.0
    pair_scatter_nm: float = float("nan")
    pair_rms_nm: float = float("nan")
    pairs_rejected: int = 0
    after_heldout: MismatchStats | None = None

    @property
    def pixel_nm(self) -> float:
        """Pixel size of the corrected grid (nm)."""
        return float(self.position_nm[1] - self.position_nm[0])

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures: mismatch before/after, spreads, pairs, lines, loop."""
        return {
            "mismatch_before_nm": self.before.median_abs_nm,
            "mismatch_after_nm": self.after.median_abs_nm,
            "mismatch_before_iqr_nm": self.before.iqr_nm,
            "mismatch_after_iqr_nm": self.after.iqr_nm,
            "mismatch_after_heldout_nm": (
                None if self.after_heldout is None else self.after_heldout.median_abs_nm
            ),
            "mismatch_before_p90_nm": self.before.p90_abs_nm,
            "mismatch_after_p90_nm": self.after.p90_abs_nm,
            "mismatch_before_signed_median_nm": self.before.median_nm,
            "mismatch_after_signed_median_nm": self.after.median_nm,
            "lines_measured_before": self.before.lines,
            "lines_measured_after": self.after.lines,
            "pairs": len(self.pairs),
            "pairs_rejected": self.pairs_rejected,
            "pair_scatter_nm": self.pair_scatter_nm,
            "pair_residual_rms_nm": self.pair_rms_nm,
            "smoothing": self.smoothing,
            "lines_with_pairs": int(np.unique(self.pairs.line).size),
            "pairs_by_kind": {
                str(k): int(np.sum(self.pairs.kind == k)) for k in np.unique(self.pairs.kind)
            },
            "loop": {
                "degree": self.loop.degree,
                "coefficients": [float(c) for c in self.loop.coefficients],
                "variable": (
                    "s = (u - u_s_nm) / half_range_nm; "
                    "f_a(u) = y_s_nm + half_range_nm * sum_k c_k s^k"
                ),
                "u_min_nm": self.loop.u_min_nm,
                "u_max_nm": self.loop.u_max_nm,
                "u_s_nm": self.loop.u_s_nm,
                "y_s_nm": self.loop.y_s_nm,
                "half_range_nm": self.loop.half_range_nm,
            },
            "corrected_pixel_nm": self.pixel_nm,
            "corrected_range_nm": [float(self.position_nm[0]), float(self.position_nm[-1])],
        }


def _resample_rows(
    img: NDArray[np.float64], y_of_column: NDArray[np.float64], grid: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Re-sample each row, known at positions ``y_of_column`` (increasing), onto ``grid``."""
    return np.stack([np.interp(grid, y_of_column, row) for row in img])


def correct_scan(
    scan: AfmScan,
    *,
    degree: int = 5,
    max_shift_nm: float | None = None,
    min_snr: float = 8.0,
    outlier_sigma: float = 4.0,
    curvature_prior: float = 0.1,
) -> LoopCorrection:
    """Fit the fast axis' symmetric loop on a real image and remap both traces (Section IV).

    Steps: (1) per-line mismatch of the raw traces (:func:`line_shifts_nm`); its median is the
    typical shift used to gate the pairing; (2) features and pairs on every line
    (:func:`scan_feature_pairs`); (3) one :meth:`SymmetricLoop.from_peaks` fit on all pairs of
    all lines (eq (23)), refitted once without pairs whose residual ``f_a(u_a) - f_d(u_d)``
    exceeds ``outlier_sigma`` robust standard deviations; (4) both traces re-sampled on a
    uniform grid of true position covering the range both traces see; (5) the mismatch again,
    and on the odd lines with a loop fitted on the even lines only (hold-out check).

    Parameters
    ----------
    scan : AfmScan
        Image with forward and backward traces.
    degree : int, optional
        Degree of ``f_a`` (paper: >= 5).
    max_shift_nm : float, optional
        Largest trace/retrace shift searched (nm). Default 10 % of the scan width.
    min_snr : float, optional
        Feature prominence over noise (see :func:`scan_feature_pairs`).
    outlier_sigma : float, optional
        Pairs whose residual ``f_a(u_a) - f_d(u_d)`` under a stiff first fit lies further than
        this many robust standard deviations from the median are dropped.
    curvature_prior : float, optional
        Expected bending ``int P''(s)^2 ds`` of the loop (> 0). Eq (23) does not see odd distortions
        of the true axis (see :mod:`piezocomp.identification.loop.symmetric`); the final fit adds
        the penalty ``smoothing * int P''^2`` with ``smoothing = (sigma / h)^2 / curvature_prior``
        (``sigma``: robust scatter of the pair residuals, ``h``: half the scan width), a Gaussian
        prior on the bending. Larger values follow the pairs more closely.
    """
    for name, image in (("backward (retrace)", scan.backward_nm), ("forward", scan.forward_nm)):
        if image is None:
            raise ValueError(
                f"{scan.source}: channel {scan.channel!r} has no {name} image; "
                "the loop needs both traces."
            )
    fw = np.asarray(scan.forward_nm, dtype=float)
    bw = np.asarray(scan.backward_nm, dtype=float)
    nx = fw.shape[1]
    if nx < 16:
        raise ValueError(f"{scan.source}: lines of {nx} pixels are too short (need >= 16).")
    px = float(scan.pixel_nm[0])
    width = float(scan.size_nm[0])
    ms = 0.1 * width if max_shift_nm is None else check_finite_scalar("max_shift_nm", max_shift_nm)
    if ms <= 0:
        raise ValueError(f"max_shift_nm must be > 0. Got {ms}.")
    curvature_prior = check_finite_scalar("curvature_prior", curvature_prior)
    if curvature_prior <= 0:
        raise ValueError(f"curvature_prior must be > 0. Got {curvature_prior}.")
    u = np.arange(nx, dtype=np.float64) * px
    before = mismatch_stats(line_shifts_nm(fw, bw, px, max_shift_nm=ms))
    typical = before.median_nm
    tolerance = max(3.0 * px, 2.0 * before.iqr_nm, 0.3 * abs(typical))
    pairs = scan_feature_pairs(
        fw, bw, u, typical_shift_nm=typical, tolerance_nm=tolerance, min_snr=min_snr
    )
    if len(pairs) <= degree:
        raise ValueError(
            f"{scan.source}: found {len(pairs)} features on both traces; a loop of degree "
            f"{degree} needs more than {degree}."
        )
    u_min, u_max = float(u[0]), float(u[-1])
    h = 0.5 * (u_max - u_min)
    keep, sigma = _agreeing_pairs(pairs, u_min, u_max, degree, outlier_sigma, scan.source)
    pairs = pairs.select(keep)
    # Stage 2: eq (23) on the kept pairs, curvature penalty from the scatter and the prior.
    smoothing = (sigma / h) ** 2 / curvature_prior
    loop = SymmetricLoop.from_peaks(
        pairs.u_ascending_nm, pairs.u_descending_nm, u_min, u_max, degree, smoothing=smoothing
    )
    res = loop.pair_residuals_nm(pairs.u_ascending_nm, pairs.u_descending_nm)
    pair_rms = float(np.sqrt(np.mean(res**2)))
    grid, fw_c, bw_c = _remap(loop, u, fw, bw, scan.source)
    after = mismatch_stats(line_shifts_nm(fw_c, bw_c, float(grid[1] - grid[0]), max_shift_nm=ms))
    heldout = _heldout_mismatch(pairs, u, fw, bw, degree, smoothing, ms, scan.source)
    return LoopCorrection(
        loop=loop,
        u_nm=readonly(u),
        position_nm=readonly(grid),
        forward_nm=readonly(fw_c),
        backward_nm=readonly(bw_c),
        pairs=pairs,
        before=before,
        after=after,
        smoothing=smoothing,
        pair_scatter_nm=sigma,
        pair_rms_nm=pair_rms,
        pairs_rejected=int((~keep).sum()),
        after_heldout=heldout,
    )


def _agreeing_pairs(
    pairs: FeaturePairs, u_min: float, u_max: float, degree: int, outlier_sigma: float, source: str
) -> tuple[NDArray[np.bool_], float]:
    """Stage 1 of :func:`correct_scan`: a stiff fit (near the least-curvature loop) measures
    the pairs' scatter; returns the pairs within ``outlier_sigma`` robust standard deviations
    of the median residual, and that standard deviation (nm)."""
    h = 0.5 * (u_max - u_min)
    stiff = SymmetricLoop.from_peaks(
        pairs.u_ascending_nm, pairs.u_descending_nm, u_min, u_max, degree, smoothing=1e-3
    )
    res = stiff.pair_residuals_nm(pairs.u_ascending_nm, pairs.u_descending_nm)
    centre = float(np.median(res))
    sigma = max(1.4826 * float(np.median(np.abs(res - centre))), 1e-9 * h)
    keep = np.abs(res - centre) <= outlier_sigma * sigma
    if keep.sum() <= degree:
        raise ValueError(
            f"{source}: only {int(keep.sum())} of {len(pairs)} feature pairs agree with "
            f"one loop; a loop of degree {degree} needs more than {degree}."
        )
    return keep, sigma


def _heldout_mismatch(
    pairs: FeaturePairs,
    u: NDArray[np.float64],
    fw: NDArray[np.float64],
    bw: NDArray[np.float64],
    degree: int,
    smoothing: float,
    max_shift_nm: float,
    source: str,
) -> MismatchStats | None:
    """The hold-out check of :func:`correct_scan`: a loop fitted on the even lines' pairs
    only, judged on the odd lines (``None`` if there are too few pairs or lines)."""
    even = pairs.line % 2 == 0
    if not (even.sum() > degree and fw.shape[0] >= 2):
        return None
    try:
        loop_even = SymmetricLoop.from_peaks(
            pairs.u_ascending_nm[even],
            pairs.u_descending_nm[even],
            float(u[0]),
            float(u[-1]),
            degree,
            smoothing=smoothing,
        )
        g_odd, f_odd, b_odd = _remap(loop_even, u, fw[1::2], bw[1::2], source)
        return mismatch_stats(
            line_shifts_nm(f_odd, b_odd, float(g_odd[1] - g_odd[0]), max_shift_nm=max_shift_nm)
        )
    except ValueError:
        return None


def _remap(
    loop: SymmetricLoop,
    u: NDArray[np.float64],
    fw: NDArray[np.float64],
    bw: NDArray[np.float64],
    source: str,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Both traces on one uniform true-position grid: forward at f_a(u), backward at f_d(u)."""
    y_f = loop.ascending(u)
    y_b = loop.descending(u)
    lo = max(float(y_f[0]), float(y_b[0]))
    hi = min(float(y_f[-1]), float(y_b[-1]))
    if not hi > lo:
        raise ValueError(f"{source}: the fitted loop leaves no position seen by both traces.")
    grid = np.linspace(lo, hi, u.size)
    return grid, _resample_rows(fw, y_f, grid), _resample_rows(bw, y_b, grid)
