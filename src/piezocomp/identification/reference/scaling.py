"""The model's scale from a grating record (the length reference of the identification).

:func:`fit_scale` runs a model over a
:class:`~piezocomp.identification.reference.grating.GratingRecord` and finds the period ``Lambda``
of the measured heights against the model's predicted positions, shared by every pass (a Fourier
series of ``2 pi (y_hat - delta_p) / Lambda`` with an offset ``delta_p`` per pass, which absorbs
slow creep and drift; forward and backward passes in equal numbers cancel the first-order stretch of
drift). ``alpha = P / Lambda`` is the factor the model's output must be multiplied by
(:func:`~piezocomp.identification.reference.frames.mapped`). :func:`scale_fits` does it for the
identification's two models, with the findings a user should read."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, minimize_scalar

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.identification.estimation.prediction import record_state
from piezocomp.identification.reference.grating import GratingRecord
from piezocomp.identification.reference.grating_angle import grating_angle
from piezocomp.model import ScannerModel, simulate

__all__ = [
    "AGREEMENT",
    "ScaleFit",
    "angle_findings",
    "check_plausible",
    "fit_scale",
    "folded",
    "referenced_map",
    "scale_fits",
    "scale_of_positions",
]

MAX_ANGLE_DEG = 5.0
"""Largest grating angle whose pitch correction is trusted without a finding."""


@dataclass(frozen=True)
class ScaleFit:
    """What :func:`fit_scale` found.

    Attributes
    ----------
    alpha : float
        Factor on the model's output that makes its lengths the grating's:
        ``P / (Lambda cos(angle))``, the pitch seen along the axis over the period found.
    alpha_std : float
        Its standard error: from the scatter of the lines' own scales with two lines or more
        (which includes what each line's roughness does to it), else from the fit's
        residuals (noise only). The pitch's own tolerance adds to it.
    line_alphas : tuple of float
        ``P / (Lambda_l cos(angle))`` of each scan line.
    period_nm : float
        ``Lambda``: the grating's period along the axis in the model's lengths (mean over
        the lines).
    residual_rms_nm : float
        Height residual of the periodic fit (noise, roughness, and the model's shape error
        seen as phase jitter).
    n_passes : int
    pass_shifts_nm : tuple of float
        ``delta_p`` of each pass (the first is 0), in the model's lengths.
    coefficients : tuple of float
        The Fourier series' ``c0, a_1..a_H, b_1..b_H`` (heights, nm).
    pitch_nm : float
        The grating's pitch the fit used.
    angle_deg : float
        The grating's angle from square to the axis, measured from the lines' shifts (NaN
        without ``line_slow_nm`` or with fewer than two lines: then taken as 0).
    line_periods_nm : tuple of float
        ``Lambda_l`` of each scan line (model's lengths).
    drift_nm_per_s : float
        The tip's drift along the axis relative to the grating, measured from the passes'
        shifts while it was scanned (mean over the lines, nm/s; NaN where the lines hold too
        few passes): taken out of the angle, which it would otherwise read.
    """

    alpha: float
    alpha_std: float
    line_alphas: tuple[float, ...]
    period_nm: float
    residual_rms_nm: float
    n_passes: int
    pass_shifts_nm: tuple[float, ...] = ()
    coefficients: tuple[float, ...] = ()
    pitch_nm: float = float("nan")
    angle_deg: float = float("nan")
    line_periods_nm: tuple[float, ...] = ()
    drift_nm_per_s: float = float("nan")

    def profile(self, x_nm: ArrayLike) -> NDArray[np.float64]:
        """The fitted grating profile at ``x_nm`` in the grating's lengths (a crest-relative
        coordinate: ``x = 0`` is ``y_hat = delta_p`` on every pass)."""
        coef = np.asarray(self.coefficients, dtype=float)
        harmonics = (coef.size - 1) // 2
        if harmonics < 1:
            raise ValueError("this ScaleFit holds no coefficients.")
        ph = 2 * np.pi * np.asarray(x_nm, dtype=float) / self.pitch_nm
        return np.asarray(_design(np.atleast_1d(ph), harmonics) @ coef).reshape(np.shape(ph))

    def summary(self) -> dict[str, Any]:
        """The scale fit, JSON-ready (``None`` for a figure not measured)."""
        return {
            "alpha": self.alpha,
            "alpha_std": self.alpha_std,
            "line_alphas": list(self.line_alphas),
            "angle_deg": None if math.isnan(self.angle_deg) else self.angle_deg,
            "drift_nm_per_s": None if math.isnan(self.drift_nm_per_s) else self.drift_nm_per_s,
            "period_nm": self.period_nm,
            "residual_rms_nm": self.residual_rms_nm,
            "passes": self.n_passes,
        }


def _design(phase: NDArray[np.float64], harmonics: int) -> NDArray[np.float64]:
    """Columns ``1, cos(m phase), sin(m phase)`` for ``m = 1..harmonics``."""
    m = np.arange(1, harmonics + 1)
    mp = np.multiply.outer(phase, m)
    return np.column_stack([np.ones_like(phase), np.cos(mp), np.sin(mp)])


def _slope(
    phase: NDArray[np.float64], coef: NDArray[np.float64], harmonics: int
) -> NDArray[np.float64]:
    """Derivative of ``_design(phase) @ coef`` with respect to ``phase``."""
    m = np.arange(1, harmonics + 1)
    mp = np.multiply.outer(phase, m)
    a, b = coef[1 : harmonics + 1], coef[harmonics + 1 :]
    return np.asarray(np.cos(mp) @ (m * b) - np.sin(mp) @ (m * a))


PLAUSIBLE_SCALE = (0.6, 1.4)
"""The scales a grating may give a model in its working frame (true over nominal length over
the working span; 0.79 on the virtual cpr5 at 1000 nm, nearer 1 on larger spans). Outside,
the reference is refused: a wrong pitch or a period of the wrong order is likelier than such
a scanner."""

AGREEMENT = (0.7, 1.43)
"""How far the grating's scale may lie from the frame map's (the calibration cycles', or the
working span's calibration condition): the window :func:`scale_fits` searches the period in,
relative to the frame map's scale. Over cpr5 samples the two agree within 15 %; a period twice
or half the grating's (a sub- or super-harmonic of its profile, which fits the heights of a
model with unmodelled creep almost as well) lies outside it, and is never taken."""

ALIAS_TOLERANCE = 0.25
"""A period ``k`` times shorter than the best on the grid is taken instead when its pass cost
is within this fraction of the best's (above it): both refined, see :func:`_fundamental`."""


def _fundamental(
    grid: NDArray[np.float64], costs: NDArray[np.float64], harmonics: int, cost: Any
) -> float:
    """The grid's best period, or the shortest of its sub-multiples that fits about as well.

    A Fourier series of ``H`` harmonics in the phase of a period ``k Lambda`` (``k <= H``)
    holds every series in the phase of ``Lambda``: a multiple of the true period fits the
    heights as well as the period itself. On long passes the cost is so sharp in the period
    that the grid's 3 % steps decide which of the two lies nearer a grid point (it put the
    scale off by a factor 2 on spans of 1400 nm and more). So the best grid point and its
    sub-multiples ``Lambda*/k`` (``k = 2..H``, within the grid) are each refined by a bounded
    search over +-3 %, and the shortest whose refined cost is within
    :data:`ALIAS_TOLERANCE` of the best refined cost is taken.
    """

    def refined(lam: float) -> tuple[float, float]:
        r = minimize_scalar(
            cost, bounds=(lam / 1.03, lam * 1.03), method="bounded", options={"xatol": lam * 1e-5}
        )
        return float(r.x), float(r.fun)

    best = int(np.argmin(costs))
    cands = {1: refined(float(grid[best]))}
    for k in range(2, int(harmonics) + 1):
        lam_k = float(grid[best]) / k
        if lam_k >= float(grid[0]) / 1.03:
            cands[k] = refined(lam_k)
    low = min(c for _, c in cands.values())
    k_best = max(k for k, (_, c) in cands.items() if c <= (1 + ALIAS_TOLERANCE) * low)
    return cands[k_best][0]


def _options(
    record: GratingRecord, harmonics: int, search: tuple[float, float], prescale: float
) -> tuple[float, float, float]:
    """The fit's options checked: ``(lo, hi, prescale)``."""
    if not isinstance(record, GratingRecord):
        raise TypeError(f"record must be a GratingRecord. Got {type(record).__name__}.")
    if isinstance(harmonics, bool) or not isinstance(harmonics, int) or harmonics < 1:
        raise ValueError(f"harmonics must be an integer >= 1. Got {harmonics!r}.")
    lo, hi = (check_finite_scalar("search", v) for v in search)
    if not 0 < lo < 1 < hi:
        raise ValueError(f"search must satisfy 0 < lo < 1 < hi. Got {search}.")
    pre = check_finite_scalar("prescale", prescale)
    if pre <= 0:
        raise ValueError(f"prescale must be > 0. Got {prescale}.")
    return lo, hi, pre


def fit_scale(
    model: ScannerModel,
    record: GratingRecord,
    *,
    harmonics: int = 3,
    search: tuple[float, float] = (0.5, 2.0),
    prescale: float = 1.0,
) -> ScaleFit:
    """The factor ``alpha`` that makes ``model``'s lengths the grating's.

    The model runs over the whole record from rest at its first command. The heights of the
    passes are fitted by one Fourier series (``harmonics`` terms) of
    ``phi = 2 pi (y_hat - delta_p) / Lambda``, with a shift ``delta_p`` per pass (the first
    is 0): bounded least squares over ``Lambda``, the shifts and the coefficients, with the
    analytic Jacobian (Levenberg-Marquardt). ``Lambda`` starts from the best of a grid (3 %
    steps over ``search`` times the pitch) on which every pass is fitted on its own.

    ``prescale`` is what the model's lengths are believed to need already (e.g. the frame
    map's ``alpha``): the search runs on the model's lengths times ``prescale``, so the window
    ``search`` is about that belief rather than about the model's raw lengths, whose scale
    the topography cannot fix. The fit returned is for ``model`` as given (``alpha`` and the
    lengths include ``prescale``).

    Raises
    ------
    ValueError
        If a pass spans less than two periods in the model's lengths, no period is found
        within the search, or the periodic fit leaves more than half the heights' spread
        (a period of the wrong frame: lengths far outside the search alias onto one inside).
    """
    if not isinstance(model, ScannerModel):
        raise TypeError(f"model must be a ScannerModel. Got {type(model).__name__}.")
    lo, hi, pre = _options(record, harmonics, search, prescale)
    y, _ = simulate(
        model, record.u_nm, record.sample_period_s, record_state(model, float(record.u_nm[0]))
    )
    return scale_of_positions(y, record, harmonics=harmonics, search=(lo, hi), prescale=pre)


def scale_of_positions(
    positions_nm: ArrayLike,
    record: GratingRecord,
    *,
    harmonics: int = 3,
    search: tuple[float, float] = (0.5, 2.0),
    prescale: float = 1.0,
) -> ScaleFit:
    """:func:`fit_scale` on given positions of the record's samples instead of a model's
    prediction (``positions_nm``, one per sample of ``record``): the factor that makes those
    lengths the grating's. A model's scale is this on its prediction; on a simulator's true
    extension it measures what the grating's fit itself adds (drift, roughness, noise, the
    angle), for diagnosis.

    Raises
    ------
    ValueError
        As :func:`fit_scale`, or if ``positions_nm`` is not one finite value per sample.
    """
    lo, hi, pre = _options(record, harmonics, search, prescale)
    y = as_finite_array("positions_nm", positions_nm, ndim=1)
    if y.shape != record.u_nm.shape:
        raise ValueError(
            f"positions_nm must hold one value per record sample ({record.u_nm.size}). "
            f"Got {y.size}."
        )
    P = record.pitch_nm
    y = pre * y
    xs = [np.asarray(y[a:b]) for a, b in record.passes]
    zs = [np.asarray(record.height_nm[a:b]) for a, b in record.passes]
    n_pass = len(xs)

    lam0 = _coarse_period(xs, zs, P, lo, hi, harmonics)
    line_ids = sorted(set(record.pass_lines or (0,)))
    pass_line = np.array([line_ids.index(v) for v in record.pass_lines or (0,) * n_pass])
    n_line, n_lam = len(line_ids), len(line_ids) + n_pass - 1  # periods, then shifts
    z = np.concatenate(zs)
    sol = _periodic_fit(xs, z, pass_line, lam0, harmonics)
    lams = np.asarray(sol.x[:n_line])
    if not (sol.success and np.all((lams > P * lo) & (lams < P * hi))):
        raise ValueError(
            f"the grating's period was not found in the model's lengths (periods {lams} nm, "
            f"search {P * lo:g}-{P * hi:g} nm; {sol.message}): is the pitch right, and the "
            "grating's lines perpendicular to the axis?"
        )
    r = sol.fun
    resid, spread = float(np.sqrt(np.mean(r**2))), float(np.std(z))
    if not resid <= 0.5 * spread:  # a period found among the lengths of a wrong frame
        raise ValueError(
            f"the grating's heights do not follow one period in the model's lengths: the "
            f"periodic fit (period {float(np.mean(lams)) / pre:.1f} nm) leaves {resid:.2f} "
            f"nm rms of the heights' {spread:.2f} nm, and must leave at most half (the "
            "model's lengths outside the search, or a wrong pitch)"
        )
    shifts = np.concatenate([[0.0], sol.x[n_line:n_lam]])
    angle, rate = grating_angle(
        record, line_ids, pass_line, shifts, float(np.mean(lams)), P / float(np.mean(lams))
    )
    alphas = P / lams / (1.0 if np.isnan(angle) else np.cos(np.radians(angle)))
    if n_line >= 2:
        alpha_std = float(np.std(alphas, ddof=1) / np.sqrt(n_line))
    else:
        sigma2 = float(r @ r) / max(r.size - sol.x.size, 1)
        lam_std = float(np.sqrt(max(sigma2 * np.linalg.pinv(sol.jac.T @ sol.jac)[0, 0], 0.0)))
        alpha_std = float(alphas[0] * lam_std / lams[0])
    return ScaleFit(  # back to the model's own lengths (prescale undone)
        alpha=float(np.mean(alphas)) * pre,
        alpha_std=alpha_std * pre,
        line_alphas=tuple(float(a) * pre for a in alphas),
        period_nm=float(np.mean(lams)) / pre,
        residual_rms_nm=float(np.sqrt(np.mean(r**2))),
        n_passes=n_pass,
        pass_shifts_nm=tuple(float(v) / pre for v in shifts),
        coefficients=tuple(float(v) for v in sol.x[n_lam:]),
        pitch_nm=P,
        angle_deg=angle,
        line_periods_nm=tuple(float(v) / pre for v in lams),
        drift_nm_per_s=rate,
    )


def _periodic_fit(
    xs: list[NDArray[np.float64]],
    z: NDArray[np.float64],
    pass_line: NDArray[np.intp],
    lam0: float,
    harmonics: int,
) -> Any:
    """Levenberg-Marquardt fit of the passes' heights ``z`` (concatenated) by one Fourier
    series of ``2 pi (x - delta_p) / Lambda_l``: ``theta = (Lambda_l per line, delta_p per
    pass but the first, the series' coefficients)``, from ``Lambda = lam0``, shifts 0 and
    the coefficients' linear fit, with the analytic Jacobian. Returns scipy's result."""
    n_pass, n_coef = len(xs), 2 * harmonics + 1
    n_line = int(pass_line.max()) + 1
    which = np.repeat(np.arange(n_pass), [x.size for x in xs])
    line_of = pass_line[which]  # line of every sample
    n_lam = n_line + n_pass - 1
    x_all = np.concatenate(xs)

    def phase(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        lam = theta[:n_line][line_of]
        deltas = np.concatenate([[0.0], theta[n_line:n_lam]])[which]
        return np.asarray(2 * np.pi * (x_all - deltas) / lam)

    def residual(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(_design(phase(theta), harmonics) @ theta[n_lam:] - z)

    def jacobian(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        ph = phase(theta)
        d = _slope(ph, theta[n_lam:], harmonics)
        lam = theta[:n_line][line_of]
        J = np.zeros((z.size, n_lam + n_coef))
        J[np.arange(z.size), line_of] = -d * ph / lam
        rows = np.flatnonzero(which > 0)
        J[rows, n_line - 1 + which[rows]] = -d[rows] * 2 * np.pi / lam[rows]
        J[:, n_lam:] = _design(ph, harmonics)
        return J

    theta0 = np.r_[np.full(n_line, lam0), np.zeros(n_pass - 1), np.zeros(n_coef)]
    theta0[n_lam:] = np.linalg.lstsq(_design(phase(theta0), harmonics), z, rcond=None)[0]
    return least_squares(residual, theta0, jac=jacobian, method="lm", x_scale="jac")


def check_plausible(fit: ScaleFit) -> None:
    """Refuse a scale outside :data:`PLAUSIBLE_SCALE` (for a model in its working frame)."""
    lo, hi = PLAUSIBLE_SCALE
    if not lo <= fit.alpha <= hi:
        raise ValueError(
            f"the grating gives the model a scale of {fit.alpha:.3f}: the scanner would move "
            f"{fit.alpha:.0%} of the nominal distance over the working span, outside the "
            f"plausible {lo:g}-{hi:g}; check the grating's pitch ({fit.pitch_nm:g} nm) and that "
            "its lines run across the axis"
        )


def angle_findings(fit: ScaleFit) -> list[str]:
    """What a user should know about the grating's angle: unmeasured with one line, or so
    large that the correction rests on the slow axis' scale."""
    if np.isnan(fit.angle_deg):
        if len(fit.line_alphas) < 2:
            return [
                "one grating line: its angle to the axis was not measured; a grating d "
                "degrees off square makes the scale too small by 1 - cos(d) (0.4 % at 5 "
                "degrees): scan several lines"
            ]
        return []
    a = abs(fit.angle_deg)
    if a <= MAX_ANGLE_DEG:
        return []
    t2 = float(np.tan(np.radians(a)) ** 2)
    return [
        f"the grating is {a:.1f} degrees off square to the axis; the pitch along the axis was "
        f"corrected by 1/cos, which rests on the slow axis moving its nominal distance "
        f"between lines: 10 % off there moves the scale by about {100 * t2 * 0.1:.2f} % "
        f"(square the grating to within {MAX_ANGLE_DEG:g} degrees)"
    ]


def scale_fits(
    models: dict[str, ScannerModel],
    reference: GratingRecord,
    heldout: dict[str, float],
    notes: list[str],
    prescale: Mapping[str, float] | None = None,
) -> dict[str, ScaleFit]:
    """The grating's scale of the ``"batch"`` and ``"rls"`` models (:func:`fit_scale`), with
    the grating's angle findings in ``notes``. A batch model whose scale cannot be found, or
    is implausible (:func:`check_plausible`),
    raises; an RLS model's is left out with a note (its lengths are far off, which the
    held-out heights show; the batch model is scaled all the same). ``prescale`` holds each
    model's frame-map ``alpha``, about which the grating's period is searched: within
    :data:`AGREEMENT` of it, so that the scale agrees with what the calibration cycles say."""
    pre = dict(prescale or {})
    try:
        batch_fit = fit_scale(
            models["batch"], reference, prescale=pre.get("batch", 1.0), search=AGREEMENT
        )
    except ValueError as exc:
        raise ValueError(
            f"{exc}. The calibration cycles give the model a scale of "
            f"{pre.get('batch', 1.0):.3f}; the grating's must lie within "
            f"{AGREEMENT[0]:g}-{AGREEMENT[1]:g} times that. Check the grating's pitch, that its "
            "lines run across the axis and that the tip images it sharply (a worn or double tip)"
        ) from None
    fits = {"batch": batch_fit}
    check_plausible(fits["batch"])
    try:
        rls_fit = fit_scale(
            models["rls"], reference, prescale=pre.get("rls", 1.0), search=AGREEMENT
        )
        check_plausible(rls_fit)
        fits = {"rls": rls_fit, **fits}
    except ValueError as exc:
        notes.append(
            f"the RLS model could not be scaled by the grating ({exc}); it is left unscaled "
            f"and is far off (held-out heights {heldout.get('rls', float('nan')):.2f} nm RMS "
            f"against the batch model's {heldout.get('batch', float('nan')):.2f}): use the "
            "batch model"
        )
    notes.extend(angle_findings(fits["batch"]))
    return fits


def referenced_map(
    alpha_ref: float, frame: tuple[float, float], center_nm: float
) -> tuple[float, float]:
    """The frame map with the grating's scale: ``alpha_ref`` about the working line's centre,
    which stays where ``frame`` put it."""
    a, b = frame
    return alpha_ref, a * center_nm + b - alpha_ref * center_nm


def folded(
    model: ScannerModel, record: GratingRecord, fit: ScaleFit
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """The passes' heights against the model's position folded onto one period of the
    grating (in its lengths, ``[0, pitch)``), for plotting: ``(x_nm, height_nm, line)``."""
    if len(fit.pass_shifts_nm) != len(record.passes) or not fit.line_periods_nm:
        raise ValueError(
            f"the fit has {len(fit.pass_shifts_nm)} pass shifts; the record has "
            f"{len(record.passes)} passes."
        )
    y, _ = simulate(
        model, record.u_nm, record.sample_period_s, record_state(model, float(record.u_nm[0]))
    )
    lines = sorted(set(record.pass_lines or (0,)))
    xs, zs, ls = [], [], []
    for (a, b), d, line in zip(
        record.passes,
        fit.pass_shifts_nm,
        record.pass_lines or (0,) * len(record.passes),
        strict=True,
    ):
        lam = fit.line_periods_nm[lines.index(line)]
        xs.append(((y[a:b] - d) / lam) % 1.0 * record.pitch_nm)
        zs.append(record.height_nm[a:b])
        ls.append(np.full(b - a, lines.index(line), dtype=np.intp))
    return np.concatenate(xs), np.concatenate(zs), np.concatenate(ls)


def _coarse_period(
    xs: list[NDArray[np.float64]],
    zs: list[NDArray[np.float64]],
    P: float,
    lo: float,
    hi: float,
    harmonics: int,
) -> float:
    """The grating's period in the model's lengths on a log grid over ``P * [lo, hi]``: each
    pass's heights fitted by a Fourier series of the position on its own
    (:func:`_fundamental` picks the fundamental among the grid's minima)."""
    extent = min(float(np.ptp(x)) for x in xs)

    def pass_cost(lam: float) -> float:
        cost = 0.0
        for x, zp in zip(xs, zs, strict=True):
            A = _design(2 * np.pi * x / lam, harmonics)
            _, res, *_ = np.linalg.lstsq(A, zp, rcond=None)
            cost += float(res[0]) if res.size else 0.0
        return cost

    grid = P * np.exp(np.arange(np.log(lo), np.log(hi), 0.03))
    grid = grid[2 * grid <= extent]
    if grid.size == 0:
        raise ValueError(
            f"a grating pass spans {extent:.1f} nm in the model's lengths, less than two "
            f"periods of {P:g} nm times {lo:g}: scan a longer span or use a finer grating."
        )
    costs = np.array([pass_cost(g) for g in grid])
    return _fundamental(grid, costs, harmonics, pass_cost)
