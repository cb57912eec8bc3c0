"""Estimation over several particle lines: the joint refinement and the RLS on every line.

With ``AcquisitionConfig.extra_lines``, the records of further particle lines refine the same
models as the first line's (eqs 16-18 summed over the lines): each line has its own height
profile ``h`` (re-indexed by the shared model before every round) and counts in units of its
own residual level, so a line that moved under the tip or reads noisier counts less. The same
functions fit the chosen models over the whole record at the end (held-out part included).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.waveforms import IdentificationWaveform
from piezocomp.identification.estimation.batch import RefineOptions, Segment, refine
from piezocomp.identification.estimation.chain import BatchStage, RLSStage
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

__all__ = ["joint_rounds", "line_penalties", "rls_on_lines", "whole_record_stages"]

Lines = list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]]
"""Each line's record: (command of the axis, measured heights, the sample's drift along the
line or ``None``, :mod:`~piezocomp.identification.estimation.line_drift`), the first line first."""


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


def rls_on_lines(
    res: RLSResult,
    profile: HeightProfile,
    lines: Lines,
    T: float,
    options: EstimationConfig,
    rounds: RoundsConfig,
    wf: IdentificationWaveform,
    fit_mask: NDArray[np.bool_],
    creep_start: float | None,
    penalties: Sequence[float],
) -> tuple[RLSResult, HeightProfile, bool]:
    """The RLS on every line (``RoundsConfig.rls_lines_passes``), started from the first
    line's estimate ``res`` (whose ``h`` is ``profile``); returns the estimate kept, the
    first line's ``h`` for it and whether the lines' estimate was kept. Each line's ``h``
    is smoothed with its penalty in ``penalties`` (:func:`line_penalties`)."""
    warmup = 2 * wf.half_cycle_samples
    n_fit = int(fit_mask.sum())
    fitted = fit_mask.copy()
    fitted[:warmup] = False
    heldout = ~fit_mask
    heldout[:warmup] = False

    def own_profiles(m: ScannerModel) -> list[HeightProfile]:
        return _lines_profiles(m, lines, T, wf, creep_start, penalties)

    try:
        profs = own_profiles(res.model)  # also the first round's
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
    done = _rls_passes(m, lines, profs, w, T, options, creep_start, rounds.rls_lines_passes, n_fit)
    if done is not None:
        last, m = done, done.model
    try:
        profs = own_profiles(m)
    except ValueError:
        return res, profile, False
    if score(m, profs) < score(res.model, first):
        return last, profs[0], True
    return res, profile, False


def whole_record_stages(
    lines: Lines,
    T: float,
    options: EstimationConfig,
    rounds: RoundsConfig,
    wf: IdentificationWaveform,
    creep_start: float | None,
    penalties: Sequence[float],
) -> tuple[BatchStage | None, RLSStage | None]:
    """The final stages of :func:`~piezocomp.identification.estimation.chain.estimate`
    (``batch_final``, ``rls_final``): the chosen models fitted over the whole record of
    every line, held-out part included (``RoundsConfig.final_rounds``,
    ``rls_final_passes``); ``None`` where it is 0."""
    whole = np.ones(lines[0][0].size, dtype=bool)

    def batch_final(model: ScannerModel, prof: HeightProfile) -> tuple[ScannerModel, HeightProfile]:
        again = replace(rounds, joint_rounds=rounds.final_rounds)
        return joint_rounds(
            model, lines, T, options, again, wf, whole, creep_start, prof, penalties
        )

    def rls_final(res: RLSResult, prof: HeightProfile) -> tuple[RLSResult, HeightProfile]:
        try:
            profs = _lines_profiles(res.model, lines, T, wf, creep_start, penalties)
        except ValueError:  # the estimate's forward trace does not advance: keep it
            return res, prof
        fitted = whole.copy()
        fitted[: 2 * wf.half_cycle_samples] = False
        w = _weights(res.model, lines, profs, T, fitted, creep_start)
        last = _rls_passes(
            res.model, lines, profs, w, T, options, creep_start, rounds.rls_final_passes
        )
        return (res, prof) if last is None else (last, profs[0])

    return (
        batch_final if rounds.final_rounds > 0 else None,
        rls_final if rounds.rls_final_passes > 0 else None,
    )


def joint_rounds(
    model: ScannerModel,
    lines: Lines,
    T: float,
    options: EstimationConfig,
    rounds: RoundsConfig,
    wf: IdentificationWaveform,
    fit_mask: NDArray[np.bool_],
    creep_start: float | None,
    first_profile: HeightProfile,
    penalties: Sequence[float],
) -> tuple[ScannerModel, HeightProfile]:
    """The batch model refined on every line at once, each line's ``h`` re-indexed by the
    shared model before each round (:func:`~piezocomp.identification.estimation.batch.refine` with
    ``extra``) and smoothed with its penalty in ``penalties`` (:func:`line_penalties`);
    returns the model and the first line's ``h``."""
    warmup = 2 * wf.half_cycle_samples
    profs = [first_profile]
    fitted = fit_mask.copy()
    fitted[:warmup] = False
    for _ in range(rounds.joint_rounds):
        profs = _lines_profiles(model, lines, T, wf, creep_start, penalties)
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
                free=options.refine_free, max_nfev=options.reindex_max_nfev,
                creep_smoothing_nm=options.creep_smoothing_nm,
                weight_smoothing_nm=options.weight_smoothing_nm,
            ),
        ).model  # fmt: skip
    return model, profs[0]
