"""Estimation over several particle lines: the joint refinement and the RLS on every line.

With ``AcquisitionConfig.extra_lines``, the records of further particle lines refine the same
models as the first line's (eqs 16-18 summed over the lines): each line has its own height
profile ``h`` (re-indexed by the shared model before every round) and counts in units of its
own residual level, so a line that moved under the tip or reads noisier counts less. The same
functions fit the chosen models over the whole record at the end (held-out part included).
:class:`SeveralLines` holds the lines and these stages; the chain of one line
(:func:`~piezocomp.identification.estimation.chain.estimate`) runs them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.waveforms import IdentificationWaveform
from piezocomp.identification.estimation.batch import RefineOptions, Segment, refine
from piezocomp.identification.estimation.config import EstimationConfig, RoundsConfig
from piezocomp.identification.estimation.prediction import (
    creep_rest,
    heldout_rms,
    model_profile,
    record_state,
)
from piezocomp.identification.estimation.rls import RLSResult, rls
from piezocomp.identification.loop.fit import LoopEstimate
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.model import ScannerModel

__all__ = ["Lines", "SeveralLines", "line_penalties"]

Lines = list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]]
"""Each line's record: (command of the axis, measured heights, the sample's drift along the
line or ``None``, :mod:`~piezocomp.identification.estimation.drift_along_line`), the first line
first."""


def _lines_rms(
    model: ScannerModel,
    lines: Lines,
    profiles: list[HeightProfile],
    T: float,
    mask: NDArray[np.bool_],
    creep_start: float | None,
) -> list[float]:
    """Each line's height residual RMS over the samples of ``mask``, through its own ``h``."""
    return [
        heldout_rms(p_i, model, u_i, z_i, T, mask, creep_start, d_i)
        for (u_i, z_i, d_i), p_i in zip(lines, profiles, strict=True)
    ]


def _lam(penalty: float) -> float | None:
    """A smoothing penalty to pass on: ``None`` (choose by GCV) when it is not finite."""
    return float(penalty) if np.isfinite(penalty) else None


def _lines_profiles(
    model: ScannerModel,
    lines: Lines,
    T: float,
    wf: IdentificationWaveform,
    creep_start: float | None,
    penalties: Sequence[float],
) -> list[HeightProfile]:
    """Each line's ``h`` indexed by ``model`` (:func:`model_profile`), smoothed with its
    penalty (:func:`line_penalties`). Raises ValueError if the model's forward trace does
    not advance."""
    forward = wf.forward_traces
    return [
        model_profile(model, u_i, z_i, T, forward, creep_start, lam=_lam(lam), shift_nm=d_i)
        for (u_i, z_i, d_i), lam in zip(lines, penalties, strict=True)
    ]


def _weights(
    model: ScannerModel,
    lines: Lines,
    profiles: list[HeightProfile],
    T: float,
    fitted: NDArray[np.bool_],
    creep_start: float | None,
) -> list[float]:
    """Each line's weight: the first line's residual RMS over its fitted samples divided by
    the line's own, so each line's residuals count in units of its own residual level."""
    rms = _lines_rms(model, lines, profiles, T, fitted, creep_start)
    return [rms[0] / r if r > 0 else 1.0 for r in rms]


def _rls_passes(
    model: ScannerModel,
    lines: Lines,
    profiles: list[HeightProfile],
    weights: Sequence[float],
    T: float,
    options: EstimationConfig,
    creep_start: float | None,
    passes: int,
    n_samples: int | None = None,
) -> RLSResult | None:
    """``passes`` single passes of the RLS (``options.rls_continue``, else ``rls_settings``)
    alternating the lines, each line's heights and ``h`` weighted, the first line last (so
    the last pass and its traces are the first line's); over the first ``n_samples`` of
    each record (``None``: all). Returns the last pass (``None`` if ``passes`` is 0)."""
    settings = replace(options.rls_continue or options.rls_settings, passes=1)
    n = slice(None) if n_samples is None else slice(0, n_samples)
    last = None
    for _ in range(passes):
        for i in [*range(1, len(lines)), 0]:
            u_i, z_i, d_i = lines[i]
            last = rls(
                u_i[n], weights[i] * z_i[n], profiles[i].scaled(weights[i]), model, T,
                settings=settings, state=record_state(model, float(u_i[0]), creep_start),
                shift_nm=None if d_i is None else d_i[n],
            )  # fmt: skip
            model = last.model
    return last


def line_penalties(
    loop: LoopEstimate,
    lines: Lines,
    wf: IdentificationWaveform,
) -> list[float]:
    """Each line's smoothing penalty for ``h`` (:meth:`HeightProfile.from_samples`): chosen
    once by GCV on the line's steady forward traces indexed by the loop (the first line's
    is the loop's own ``h``), and kept when a model re-indexes the line (it moves the
    positions by a fraction of a per cent of the span)."""
    out = [loop.profile.penalty]
    for u_i, z_i, _ in lines[1:]:
        heights = np.array([z_i[wf.ascending(c)] for c in range(1, wf.n_steady)])
        out.append(HeightProfile.from_loop(loop.loop, u_i[wf.ascending(1)], heights).penalty)
    return out


@dataclass(frozen=True)
class SeveralLines:
    """The records of every line of one axis and the stages that use them all, run by
    :func:`~piezocomp.identification.estimation.chain.estimate` at the end of its chains.

    Attributes
    ----------
    lines : Lines
        Each line's record, the first line (the one the chain estimates on) first.
    sample_period_s : float
    waveform : IdentificationWaveform
    fit_mask : ndarray of bool
        The fitted samples of every line (a prefix; the rest is held out).
    creep_start_nm : float or None
        The creep states before each record
        (:func:`~piezocomp.identification.estimation.prediction.record_state`).
    penalties : tuple of float
        Each line's smoothing of ``h`` (:func:`line_penalties`).
    options : EstimationConfig
    rounds : RoundsConfig
    """

    lines: Lines
    sample_period_s: float
    waveform: IdentificationWaveform
    fit_mask: NDArray[np.bool_]
    creep_start_nm: float | None
    penalties: tuple[float, ...]
    options: EstimationConfig
    rounds: RoundsConfig

    @property
    def further(self) -> bool:
        """Whether there are lines beyond the first."""
        return len(self.lines) > 1

    def _profiles(self, model: ScannerModel) -> list[HeightProfile]:
        return _lines_profiles(model, self.lines, self.sample_period_s, self.waveform,
                               self.creep_start_nm, self.penalties)  # fmt: skip

    def _fitted(self, mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """``mask`` without the warm-up (the play states' two half cycles)."""
        fitted = mask.copy()
        fitted[: 2 * self.waveform.half_cycle_samples] = False
        return fitted

    def joint(
        self, model: ScannerModel, profile: HeightProfile
    ) -> tuple[ScannerModel, HeightProfile]:
        """The batch chain's last stage: the model refined on every line at once
        (``RoundsConfig.joint_rounds``, :meth:`joint_over`); unchanged with one line."""
        if not self.further:
            return model, profile
        return self.joint_over(model, profile, self.fit_mask, self.rounds.joint_rounds)

    def joint_over(
        self, model: ScannerModel, profile: HeightProfile, fit_mask: NDArray[np.bool_], rounds: int
    ) -> tuple[ScannerModel, HeightProfile]:
        """``rounds`` rounds of the batch model refined on every line at once over the
        samples of ``fit_mask``, each line's ``h`` re-indexed by the shared model before
        each round (:func:`~piezocomp.identification.estimation.batch.refine` with
        ``extra``) and smoothed with its penalty; returns the model and the first line's
        ``h`` (``profile`` if ``rounds`` is 0)."""
        o, T, creep_start, lines = (
            self.options,
            self.sample_period_s,
            self.creep_start_nm,
            self.lines,
        )
        warmup = 2 * self.waveform.half_cycle_samples
        profs = [profile]
        fitted = self._fitted(fit_mask)
        for _ in range(rounds):
            profs = self._profiles(model)
            # each line's residuals in units of its own residual RMS
            weights = _weights(model, lines, profs, T, fitted, creep_start)
            segments = [
                Segment(u_i, w_i * z_i, output=p_i.scaled(w_i),
                        state=record_state(model, float(u_i[0]), creep_start),
                        creep_rest_nm=creep_rest(u_i[0], creep_start),
                        fit_mask=fit_mask, warmup_samples=warmup, shift_nm=d_i)
                for (u_i, z_i, d_i), p_i, w_i in zip(lines[1:], profs[1:], weights[1:], strict=True)
            ]  # fmt: skip
            u0, z0, d0 = lines[0]
            model = refine(
                model, u0, z0, T, output=profs[0],
                state=record_state(model, float(u0[0]), creep_start), fit_mask=fit_mask,
                warmup_samples=warmup, extra=segments, shift_nm=d0,
                creep_rest_nm=creep_rest(u0[0], creep_start),
                options=RefineOptions(
                    free=o.refine_free, max_nfev=o.reindex_max_nfev,
                    creep_smoothing_nm=o.creep_smoothing_nm,
                    weight_smoothing_nm=o.weight_smoothing_nm,
                ),
            ).model  # fmt: skip
        return model, profs[0]

    def rls(self, res: RLSResult, profile: HeightProfile) -> tuple[RLSResult, HeightProfile, bool]:
        """The RLS chain's last stage: the RLS on every line (``RoundsConfig.rls_lines_passes``),
        started from the first line's estimate ``res`` (whose ``h`` is ``profile``); returns
        the estimate kept, the first line's ``h`` for it and whether the lines' estimate was
        kept (it is when it predicts the lines' held-out heights better)."""
        if not self.further or self.rounds.rls_lines_passes <= 0:
            return res, profile, False
        lines, T, creep_start = self.lines, self.sample_period_s, self.creep_start_nm
        fitted = self._fitted(self.fit_mask)
        heldout = self._fitted(~self.fit_mask)
        try:
            profs = self._profiles(res.model)  # also the first round's
        except ValueError:
            return res, profile, False
        first = [profile, *profs[1:]]  # the first line as its estimate saw it
        level = _lines_rms(res.model, lines, first, T, fitted, creep_start)  # the yardstick
        if min(level) <= 0:
            return res, profile, False

        def score(m: ScannerModel, profs: list[HeightProfile]) -> float:
            rms = _lines_rms(m, lines, profs, T, heldout, creep_start)
            return float(sum(h / s for h, s in zip(rms, level, strict=True)))

        m, last = res.model, res
        w = _weights(m, lines, profs, T, fitted, creep_start)
        done = _rls_passes(m, lines, profs, w, T, self.options, creep_start,
                           self.rounds.rls_lines_passes, int(self.fit_mask.sum()))  # fmt: skip
        if done is not None:
            last, m = done, done.model
        try:
            profs = self._profiles(m)
        except ValueError:
            return res, profile, False
        if score(m, profs) < score(res.model, first):
            return last, profs[0], True
        return res, profile, False

    def whole_batch(
        self, model: ScannerModel, profile: HeightProfile
    ) -> tuple[ScannerModel, HeightProfile]:
        """After the held-out scoring: the chosen batch model fitted over the whole record of
        every line, held-out part included (``RoundsConfig.final_rounds``)."""
        whole = np.ones(self.lines[0][0].size, dtype=bool)
        return self.joint_over(model, profile, whole, self.rounds.final_rounds)

    def whole_rls(self, res: RLSResult, profile: HeightProfile) -> tuple[RLSResult, HeightProfile]:
        """After the held-out scoring: the RLS estimate run over the whole record of every
        line (``RoundsConfig.rls_final_passes``); unchanged with 0 passes or when its forward
        trace does not advance."""
        if self.rounds.rls_final_passes <= 0:
            return res, profile
        try:
            profs = self._profiles(res.model)
        except ValueError:  # the estimate's forward trace does not advance: keep it
            return res, profile
        whole = np.ones(self.lines[0][0].size, dtype=bool)
        w = _weights(res.model, self.lines, profs, self.sample_period_s, self._fitted(whole),
                     self.creep_start_nm)  # fmt: skip
        last = _rls_passes(res.model, self.lines, profs, w, self.sample_period_s, self.options,
                           self.creep_start_nm, self.rounds.rls_final_passes)  # fmt: skip
        return (res, profile) if last is None else (last, profs[0])
