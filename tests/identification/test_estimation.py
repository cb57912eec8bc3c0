"""The estimation stage of the sensorless identification: creep spectrum, record state,
RLS + batch + order selection on an exact model (mathematics only: the data come from the
model family itself)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pytest

from piezocomp.identification.acquisition.waveforms import identification_waveform
from piezocomp.identification.estimation.candidates import DEFAULT_CREEP_TAU_RANGE_S, creep_spectrum
from piezocomp.identification.estimation.chain import estimate
from piezocomp.identification.estimation.config import EstimationConfig, RoundsConfig
from piezocomp.identification.estimation.prediction import (
    heldout_rms,
    model_profile,
    predicted_forward_trace,
    record_state,
)
from piezocomp.identification.estimation.rls import RLSSettings, rls
from piezocomp.identification.estimation.several_lines import SeveralLines
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.model import ModelState, ScannerModel, simulate

T = 0.008
BARE = dict(
    order_tolerance=0.02, reindex_max_nfev=None, rls_continue=None, rls_start=None,
    creep_smoothing_nm=0.0, weight_smoothing_nm=0.0, rls_reindex_rounds=0,
    batch_restart_ratio=None, workers=1,
)  # fmt: skip
"""The estimation without the research chain's extra stages (the tests' small records)."""
TAU = creep_spectrum(6, (0.1, 500.0))
R = np.array([60.0, 140.0, 230.0, 330.0, 420.0])
TRUE = ScannerModel(
    offset_nm=2.0,
    gain=0.75,
    thresholds_nm=R,
    weights=np.array([0.06, 0.05, 0.04, 0.03, 0.02]),
    creep_time_constants_s=TAU,
    creep_gains=np.array([0.01, 0.02, 0.015, 0.02, 0.01, 0.02]),
)


def _profile() -> HeightProfile:
    rng = np.random.default_rng(1)
    centres = np.sort(rng.uniform(-560, 560, 30))
    grid = np.linspace(-800, 800, 6401)
    h = sum(12 * np.exp(-0.5 * ((grid - c) / 10) ** 2) for c in centres)
    return HeightProfile.from_samples(grid, h, lam=1e-8, step_nm=0.25)


def test_creep_spectrum_is_log_uniform_and_checked():
    tau = creep_spectrum(5, (0.1, 1000.0))
    assert tau[0] == pytest.approx(0.1) and tau[-1] == pytest.approx(1000.0)
    assert np.allclose(np.diff(np.log10(tau)), 1.0)
    assert creep_spectrum(1, (1.0, 100.0)) == pytest.approx([10.0])
    assert creep_spectrum(0).size == 0
    assert creep_spectrum(3)[0] == DEFAULT_CREEP_TAU_RANGE_S[0]
    with pytest.raises(ValueError, match="n_creep"):
        creep_spectrum(-1)
    with pytest.raises(ValueError, match="tau_range_s"):
        creep_spectrum(3, (10.0, 1.0))


def test_record_state_places_play_and_creep_states():
    st = record_state(TRUE, -500.0, 0.0)
    assert np.all(st.play_nm == -500.0) and np.all(st.creep_nm == 0.0)
    assert st.u_prev_nm == -500.0
    rest = record_state(TRUE, -500.0)
    at_rest = ModelState.at_rest(TRUE, -500.0)
    assert np.array_equal(rest.packed(), at_rest.packed())


def _record():
    wf = identification_waveform(
        0, 1000, 250, T, n_steady=2, n_decaying=8, n_random=12, max_dwell_s=3.0, rng=2
    )
    u = wf.u_nm
    prof = _profile()
    # the scanner was scanning about the centre before the record: creep states at 0
    y, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    return wf, u, prof, np.asarray(prof(y))


STAGES = ("joint", "rls", "whole_batch", "whole_rls")
"""The stages :class:`SeveralLines` ends the chains with."""


@dataclass(frozen=True)
class _Hooked(SeveralLines):
    """One line whose chain-end stages are the test's functions ``(x, h) -> (x, h)``: what is
    tested is how the chain uses them, not what they do."""

    hooks: dict[str, Any] = field(default_factory=dict)

    def joint(self, model, profile):
        f = self.hooks.get("joint")
        return super().joint(model, profile) if f is None else f(model, profile)

    def rls(self, res, profile):
        f = self.hooks.get("rls")
        return super().rls(res, profile) if f is None else (*f(res, profile), False)

    def whole_batch(self, model, profile):
        f = self.hooks.get("whole_batch")
        return super().whole_batch(model, profile) if f is None else f(model, profile)

    def whole_rls(self, res, profile):
        f = self.hooks.get("whole_rls")
        return super().whole_rls(res, profile) if f is None else f(res, profile)


def _estimate(wf, u, z, prof, creep_start, reindex_rounds=0, selection_rounds=None, **kw):
    n = u.size
    fit = np.zeros(n, dtype=bool)
    fit[: n - n // 4] = True

    def initial(nh: int, taus: np.ndarray) -> ScannerModel:
        return ScannerModel(
            offset_nm=0.0,
            gain=0.8,
            thresholds_nm=R,
            weights=np.full(nh, 0.035),
            creep_time_constants_s=taus,
            creep_gains=np.zeros(taus.size),
        )

    hooks = {k: kw.pop(k) for k in STAGES if k in kw}
    options = EstimationConfig(
        orders=kw.pop("orders", ((5, 6),)),
        rls_settings=RLSSettings(
            alpha="unit", p0=0.1, passes=2, k0=3000, free=("c", "a", "w", "y0")
        ),
        creep_tau_range_s=(0.1, 500.0),
        reindex_rounds=reindex_rounds,
        selection_rounds=selection_rounds,
        **{**BARE, "refine_max_nfev": 15, **kw},
    )
    no_rounds = RoundsConfig(final_rounds=0, rls_final_passes=0)
    lines = None
    if hooks:
        lines = _Hooked([(u, z, None)], T, wf, fit, creep_start, (prof.penalty,), options,
                        no_rounds, hooks)  # fmt: skip
    return estimate(
        u,
        z,
        T,
        prof,
        initial,
        fit_mask=fit,
        warmup_samples=2 * wf.half_cycle_samples,
        options=options,
        creep_start_nm=creep_start,
        forward_traces=wf.forward_traces,
        lines=lines,
    )


def test_estimate_recovers_an_exact_model_with_the_right_creep_start():
    """Exact model family, thresholds and time constants as in the data: the held-out height
    error falls to a fraction of a nm, and the predicted extension follows the truth; with the
    creep states wrongly started at the first command, half a span away, it does not."""
    wf, u, prof, z = _record()
    good = _estimate(wf, u, z, prof, 0.0)
    assert good.selection.n_play == 5 and good.selection.n_creep == 6
    assert good.heldout_rms_nm["batch"] < 0.3
    assert good.heldout_rms_nm["batch"] <= good.heldout_rms_nm["initial"]
    y_true, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    y_hat, _ = simulate(good.batch_model, u, T, record_state(good.batch_model, u[0], 0.0))
    k = 2 * wf.half_cycle_samples
    assert np.max(np.abs(y_hat[k:] - y_true[k:])) < 1.5
    bad = _estimate(wf, u, z, prof, None)
    assert bad.heldout_rms_nm["batch"] > 2.0 * good.heldout_rms_nm["batch"]


def test_heldout_rms_uses_the_creep_start():
    _wf, u, prof, z = _record()
    mask = np.zeros(u.size, dtype=bool)
    mask[u.size // 2 :] = True
    assert heldout_rms(prof, TRUE, u, z, T, mask, 0.0) < 1e-9
    assert heldout_rms(prof, TRUE, u, z, T, mask, None) > 0.1


def test_heldout_rms_leaves_out_positions_beyond_the_profile():
    """Positions beyond ``h``'s table are not scored (``h`` is unknown there): a profile
    that covers only part of the record, and a wrong height beyond it, change nothing; a
    table that covers none of the held-out positions gives NaN."""
    _wf, u, prof, z = _record()
    y, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    mask = np.zeros(u.size, dtype=bool)
    mask[u.size // 2 :] = True
    grid = np.linspace(-300.0, 300.0, 2401)
    part = HeightProfile.from_samples(grid, prof(grid), lam=1e-8, step_nm=0.25)
    inside = mask & (y >= -300.0) & (y <= 300.0)
    assert 0 < inside.sum() < mask.sum()
    z_bad = z.copy()
    z_bad[mask & ~inside] += 50.0  # heights the table never saw
    expected = np.sqrt(np.mean((part(y[inside]) - z[inside]) ** 2))
    assert heldout_rms(part, TRUE, u, z_bad, T, mask, 0.0) == pytest.approx(expected)
    far = HeightProfile.from_samples(grid + 5000.0, prof(grid), lam=1e-8, step_nm=0.25)
    assert np.isnan(heldout_rms(far, TRUE, u, z, T, mask, 0.0))


def test_estimate_checks_the_fit_mask():
    _wf, u, prof, z = _record()
    holes = np.ones(u.size, dtype=bool)
    holes[10] = False
    with pytest.raises(ValueError, match="prefix"):
        estimate(
            u,
            z,
            T,
            prof,
            lambda nh, taus: TRUE,
            fit_mask=holes,
            warmup_samples=0,
            options=EstimationConfig(
                orders=((5, 6),), rls_settings=RLSSettings(), creep_tau_range_s=(0.1, 500.0), **BARE
            ),
        )


def test_model_profile_indexes_the_steady_traces_by_the_model():
    wf, u, _prof, z = _record()
    fwd = wf.forward_traces
    got = model_profile(TRUE, u, z, T, fwd, 0.0)
    y, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    inside = (y > -450) & (y < 450)
    assert np.max(np.abs(got(y[inside]) - z[inside])) < 0.05
    with pytest.raises(ValueError, match="forward_traces"):
        model_profile(TRUE, u, z, T, [], 0.0)
    with pytest.raises(ValueError, match="advances on"):
        model_profile(TRUE, u, z, T, [wf.descending(1)], 0.0)


def _affine_error(y_hat, y_true):
    coef = np.polyfit(y_hat, y_true, 1)
    return float(np.max(np.abs(y_true - np.polyval(coef, y_hat))))


def test_reindexing_undoes_an_odd_distortion_of_the_loop_frame():
    """``h`` indexed by a loop with an odd distortion (which eq 23 cannot see): the refined
    model inherits it; re-indexing ``h`` by the model (``reindex_rounds``) removes most of it,
    because the minor loops of part B do not fit a distorted frame with PI structure."""
    wf, u, _prof, z = _record()
    y_true, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    fwd = wf.ascending(1)

    def warp(y):  # odd, increasing, fixes +-500: a distortion eq (23) cannot see
        s = y / 500.0
        return y + 25.0 * (s**3 - s)

    distorted = HeightProfile.from_positions(warp(y_true[fwd]), z[fwd])
    k = 2 * wf.half_cycle_samples
    errors = {}
    for rounds in (0, 3):
        est = _estimate(wf, u, z, distorted, 0.0, reindex_rounds=rounds)
        y_hat, _ = simulate(est.batch_model, u, T, record_state(est.batch_model, u[0], 0.0))
        errors[rounds] = _affine_error(y_hat[k:], y_true[k:])
        if rounds:
            assert est.batch_profile is not distorted
        else:
            assert est.batch_profile is distorted
    assert errors[0] > 1.0  # 1.7 nm when written
    assert errors[3] < 0.2 * errors[0]  # 0.08 nm when written
    with pytest.raises(ValueError, match="reindex_rounds"):
        _estimate(wf, u, z, distorted, 0.0, reindex_rounds=-1)


def test_selection_rounds_continue_the_chosen_orders():
    """The chosen orders continue their re-indexing after the comparison: the same rounds in
    the same order as when every candidate gets them all (one candidate: identical)."""
    wf, u, _prof, z = _record()
    y_true, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    fwd = wf.ascending(1)
    start = HeightProfile.from_positions(1.01 * y_true[fwd], z[fwd])
    full = _estimate(wf, u, z, start, 0.0, reindex_rounds=2)
    split = _estimate(wf, u, z, start, 0.0, reindex_rounds=2, selection_rounds=1)
    none = _estimate(wf, u, z, start, 0.0, reindex_rounds=2, selection_rounds=0)
    for est in (split, none):
        assert np.array_equal(est.batch_model.weights, full.batch_model.weights)
        assert est.batch_model.gain == full.batch_model.gain
        assert np.array_equal(est.batch_profile.values_nm, full.batch_profile.values_nm)
    one = _estimate(wf, u, z, start, 0.0, reindex_rounds=1)
    assert not np.array_equal(one.batch_model.weights, full.batch_model.weights)
    more = _estimate(wf, u, z, start, 0.0, reindex_rounds=2, selection_rounds=3)  # capped at 2
    assert np.array_equal(more.batch_model.weights, full.batch_model.weights)


def test_sensorless_config_checks_the_reindexing_settings():
    from piezocomp.identification.config import IdentifyConfig

    for bad in (0, True, 2.5):
        with pytest.raises(ValueError, match="reindex_max_nfev"):
            IdentifyConfig().updated(reindex_max_nfev=bad)

    for bad in (-1, True, 1.5):
        with pytest.raises(ValueError, match="selection_rounds"):
            IdentifyConfig().updated(selection_rounds=bad)
    assert (
        IdentifyConfig()
        .updated(reindex_rounds=4, selection_rounds=0)
        .estimation.selection_rounds_used
        == 0
    )
    # more than reindex_rounds (e.g. the default with reindex_rounds=0): every round
    assert IdentifyConfig().updated(reindex_rounds=0).estimation.selection_rounds_used == 0
    assert (
        IdentifyConfig()
        .updated(reindex_rounds=4, selection_rounds=None)
        .estimation.selection_rounds_used
        == 4
    )


def test_the_research_config_holds_the_estimation_stages_settings_once():
    """The estimation stage's settings are the configuration's ``estimation``, the options the
    estimation runs with: a change by name reaches it and nothing else."""
    from dataclasses import fields

    from piezocomp.identification.config import IdentifyConfig

    cfg = IdentifyConfig().updated(order_tolerance=0.1, creep_smoothing_nm=5.0, workers=2)
    opts = cfg.estimation
    assert type(opts) is EstimationConfig
    changed = {"order_tolerance": 0.1, "creep_smoothing_nm": 5.0, "workers": 2}
    for f in fields(EstimationConfig):
        want = changed.get(f.name, getattr(EstimationConfig(), f.name))
        assert getattr(opts, f.name) == want, f.name
    assert EstimationConfig() == IdentifyConfig().estimation


def test_estimate_without_the_batch_step_keeps_the_rls_model():
    wf, u, prof, z = _record()
    est = _estimate(wf, u, z, prof, 0.0, reindex_rounds=2, refine_max_nfev=0)
    assert est.refine is None and est.batch_model is est.rls.model
    assert est.batch_profile is prof
    with pytest.raises(ValueError, match="reindex_max_nfev"):
        _estimate(wf, u, z, prof, 0.0, reindex_rounds=1, reindex_max_nfev=0)


def test_rls_continue_runs_the_chosen_rls_on():
    """``rls_continue`` runs the RLS on from its estimate with its own settings
    (the batch model, started from the candidates' RLS, does not change)."""
    wf, u, prof, z = _record()
    base = _estimate(wf, u, z, prof, 0.0)
    more_settings = RLSSettings(
        alpha="unit", p0=0.1, passes=2, k0=3000, free=("c", "a", "w", "y0"), clip_nm=1.0
    )
    more = _estimate(wf, u, z, prof, 0.0, rls_continue=more_settings)
    n_fit = u.size - u.size // 4
    m = base.rls.model
    by_hand = rls(u[:n_fit], z[:n_fit], prof, m, T, settings=more_settings,
                  state=record_state(m, u[0], 0.0))  # fmt: skip
    np.testing.assert_array_equal(more.rls.theta, by_hand.theta)
    assert not np.array_equal(more.rls.theta, base.rls.theta)
    assert np.array_equal(more.batch_model.weights, base.batch_model.weights)
    with pytest.raises(TypeError, match="rls_continue"):
        _estimate(wf, u, z, prof, 0.0, rls_continue=140)


def test_rls_start_gives_the_rls_chain_its_own_first_run():
    """``rls_start``: the RLS chain's estimate is its own run from the candidate's start,
    then the continuation from it; the batch model, started from the candidates'
    ``rls_settings`` estimates, does not change; threads give the same."""
    wf, u, prof, z = _record()
    settings = RLSSettings(alpha="unit", p0=0.1, passes=2, k0=3000, free=("c", "a", "w", "y0"))
    start = replace(settings, clip_nm=0.5)
    again = replace(settings, passes=1)
    base = _estimate(wf, u, z, prof, 0.0, rls_continue=again)
    own = _estimate(wf, u, z, prof, 0.0, rls_continue=again, rls_start=start)
    n_fit = u.size - u.size // 4
    init = ScannerModel(
        offset_nm=0.0, gain=0.8, thresholds_nm=R, weights=np.full(5, 0.035),
        creep_time_constants_s=creep_spectrum(6, (0.1, 500.0)), creep_gains=np.zeros(6),
    )  # fmt: skip
    first = rls(u[:n_fit], z[:n_fit], prof, init, T, settings=start,
                state=record_state(init, u[0], 0.0))  # fmt: skip
    m = first.model
    by_hand = rls(u[:n_fit], z[:n_fit], prof, m, T, settings=again,
                  state=record_state(m, u[0], 0.0))  # fmt: skip
    np.testing.assert_array_equal(own.rls.theta, by_hand.theta)
    assert not np.array_equal(own.rls.theta, base.rls.theta)
    np.testing.assert_array_equal(own.batch_model.weights, base.batch_model.weights)
    assert own.heldout_rms_nm["batch"] == base.heldout_rms_nm["batch"]
    # without a continuation the chain keeps its own first run
    alone = _estimate(wf, u, z, prof, 0.0, rls_start=start)
    np.testing.assert_array_equal(alone.rls.theta, first.theta)
    kw = dict(orders=((5, 3), (5, 6)), rls_continue=again, rls_start=start)
    serial = _estimate(wf, u, z, prof, 0.0, workers=1, **kw)
    threads = _estimate(wf, u, z, prof, 0.0, workers=2, **kw)
    np.testing.assert_array_equal(threads.rls.theta, serial.rls.theta)
    assert threads.heldout_rms_nm == serial.heldout_rms_nm
    with pytest.raises(TypeError, match="rls_start"):
        _estimate(wf, u, z, prof, 0.0, rls_start={"clip_nm": 2.0})


def test_sensorless_config_checks_the_priors_and_the_rls_continuation():
    from piezocomp.identification.config import IdentifyConfig

    for name in ("creep_smoothing_nm", "weight_smoothing_nm"):
        for bad in (-1.0, float("nan")):
            with pytest.raises(ValueError, match=name):
                IdentifyConfig().updated(**{name: bad})
    with pytest.raises(TypeError, match="rls_continue"):
        IdentifyConfig().updated(rls_continue=140)  # type: ignore[arg-type]
    assert IdentifyConfig().updated(rls_continue=None).estimation.rls_continue is None
    with pytest.raises(TypeError, match="rls_start"):
        IdentifyConfig().updated(rls_start=20)  # type: ignore[arg-type]
    slow = RLSSettings(min_time_constant_s=1.0)
    with pytest.raises(ValueError, match=r"rls_start\.min_time_constant_s"):
        IdentifyConfig().updated(rls_start=slow)


def test_model_profile_leaves_out_a_fast_creep_backstep_after_the_reversal():
    """A large creep mode faster than the ramp carries the predicted position back for a few
    samples after the reversal; those samples are left out and the profile is built."""
    wf, u, _prof, z = _record()
    fast = ScannerModel(offset_nm=0.0, gain=0.3, thresholds_nm=R, weights=TRUE.weights,
                        creep_time_constants_s=[0.05], creep_gains=[0.5])  # fmt: skip
    fwd = wf.forward_traces
    y = predicted_forward_trace(fast, u, T, fwd, 0.0)
    assert np.any(np.diff(y) <= 0)  # the backstep the test is about
    p = model_profile(fast, u, z, T, fwd, 0.0)
    lo, hi = p.y_range_nm
    assert lo >= y[0] - 1e-9 and hi <= y.max() + 1e-9


def test_sensorless_config_keeps_the_rls_bounds_below_the_creep_spectrum():
    from piezocomp.identification.config import IdentifyConfig

    cfg = IdentifyConfig()
    est = cfg.estimation
    assert est.rls_settings.min_time_constant_s <= est.creep_tau_range_s[0]
    with pytest.raises(ValueError, match="min_time_constant_s"):
        IdentifyConfig().updated(creep_tau_range_s=(0.005, 2000.0))
    IdentifyConfig().updated(creep_tau_range_s=(0.05, 2000.0))  # a narrower spectrum is fine


def test_rls_reindex_rounds_keep_the_round_with_the_best_heldout_heights():
    """``rls_reindex_rounds`` re-indexes ``h`` by the RLS estimate itself and runs the RLS on
    it again; the round kept predicts the held-out heights best, each through its own ``h``.
    Here ``h`` starts bent by an odd distortion of the branch (the loop's weak part, Section
    IV) that no model of the family reproduces, and re-indexing undoes part of it."""
    wf, u, _prof, z = _record()
    y_true, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    fwd = wf.forward_traces
    y_f = y_true[fwd[0]]
    bent = HeightProfile.from_positions(y_f + 6.0 * np.sin(np.pi * y_f / 500.0), z[fwd[0]])
    again = RLSSettings(alpha="unit", p0=0.1, passes=3, k0=3000, free=("c", "a", "w", "y0"))
    base = _estimate(wf, u, z, bent, 0.0, rls_continue=again)
    assert base.rls_round == 0 and base.rls_profile is bent
    est = _estimate(wf, u, z, bent, 0.0, rls_continue=again, rls_reindex_rounds=2,
                    rls_reindex_passes=3)  # fmt: skip
    assert est.rls_round >= 1 and est.rls_profile is not bent
    assert est.heldout_rms_nm["rls"] < 0.8 * base.heldout_rms_nm["rls"]
    n = u.size
    held = np.zeros(n, dtype=bool)
    held[n - n // 4 :] = True
    assert est.heldout_rms_nm["rls"] == pytest.approx(
        heldout_rms(est.rls_profile, est.rls.model, u, z, T, held, 0.0), rel=1e-12
    )
    # round 1 by hand: h indexed by the continued estimate (smoothed as the first h was),
    # then 3 passes on it
    m0 = base.rls.model
    p1 = model_profile(m0, u, z, T, fwd, 0.0, lam=bent.penalty)
    n_fit = n - n // 4
    r1 = rls(u[:n_fit], z[:n_fit], p1, m0, T, settings=again, state=record_state(m0, u[0], 0.0))
    one = _estimate(wf, u, z, bent, 0.0, rls_continue=again, rls_reindex_rounds=1,
                    rls_reindex_passes=3)  # fmt: skip
    assert one.rls_round == 1
    np.testing.assert_array_equal(one.rls.theta, r1.theta)
    # the batch model does not depend on the RLS's rounds
    assert np.array_equal(est.batch_model.weights, base.batch_model.weights)
    for name, bad in (("rls_reindex_rounds", -1), ("rls_reindex_rounds", True),
                      ("rls_reindex_passes", 0), ("rls_reindex_passes", 2.5)):  # fmt: skip
        with pytest.raises(ValueError, match=name):
            _estimate(wf, u, z, bent, 0.0, **{name: bad})


def test_sensorless_config_checks_the_rls_reindexing():
    from piezocomp.identification.config import IdentifyConfig

    for name, bad in (("rls_reindex_rounds", -1), ("rls_reindex_rounds", 1.5),
                      ("rls_reindex_passes", 0), ("rls_reindex_passes", True)):  # fmt: skip
        with pytest.raises(ValueError, match=name):
            IdentifyConfig().updated(**{name: bad})
    assert IdentifyConfig().updated(rls_reindex_rounds=0).estimation.rls_reindex_rounds == 0


def test_the_rls_on_every_line_is_kept_when_it_predicts_them_better():
    """``RoundsConfig.rls_lines_passes``: the RLS run on every line (each with its own
    ``h`` re-indexed by the estimate, weighted by its residual level) replaces the first
    line's estimate when it predicts the lines' held-out heights better. Here the first
    line's ``h`` is bent (its estimate inherits the bend) and a second line is clean."""
    from piezocomp.identification.config import IdentifyConfig

    wf, u, true_h, z = _record()
    y_true, _ = simulate(TRUE, u, T, record_state(TRUE, u[0], 0.0))
    fwd = wf.forward_traces
    y_f = y_true[fwd[0]]
    bent = HeightProfile.from_positions(y_f + 6.0 * np.sin(np.pi * y_f / 500.0), z[fwd[0]])
    rng = np.random.default_rng(7)
    grid = np.linspace(-800, 800, 6401)
    other = sum(12 * np.exp(-0.5 * ((grid - c) / 10) ** 2) for c in rng.uniform(-560, 560, 30))
    z2 = np.asarray(HeightProfile.from_samples(grid, other, lam=1e-8, step_nm=0.25)(y_true))
    n = u.size
    fit = np.zeros(n, dtype=bool)
    fit[: n - n // 4] = True
    settings = RLSSettings(alpha="unit", p0=0.1, passes=3, k0=3000, free=("c", "a", "w", "y0"))
    start = ScannerModel(offset_nm=0.0, gain=0.8, thresholds_nm=R, weights=np.full(5, 0.035),
                         creep_time_constants_s=TAU, creep_gains=np.zeros(TAU.size))  # fmt: skip
    res = rls(u[: n - n // 4], z[: n - n // 4], bent, start, T, settings=settings,
              state=record_state(start, u[0], 0.0))  # fmt: skip
    cfg = IdentifyConfig().updated(rls_settings=settings, rls_continue=settings,
                           creep_tau_range_s=(0.1, 500.0), rls_reindex_rounds=1,
                           rls_lines_passes=2)  # fmt: skip
    lams = [bent.penalty, HeightProfile.from_positions(y_f, [z2[f] for f in fwd]).penalty]
    lines = SeveralLines([(u, z, None), (u, z2, None)], T, wf, fit, 0.0, tuple(lams),
                         cfg.estimation, cfg.rounds)  # fmt: skip
    out, prof, kept = lines.rls(res, bent)
    assert kept and prof is not bent and out is not res
    held = ~fit
    held[: 2 * wf.half_cycle_samples] = False
    assert heldout_rms(prof, out.model, u, z, T, held, 0.0) < heldout_rms(
        bent, res.model, u, z, T, held, 0.0
    )
    # from the exact model on the true h, with a second "line" whose heights are the first's
    # read 2 s late (no scanner gives them): the lines' estimate predicts the
    # heights worse, and the first line's is kept
    exact = rls(u[: n - n // 4], z[: n - n // 4], true_h, TRUE, T, settings=settings,
                state=record_state(TRUE, u[0], 0.0))  # fmt: skip
    lag = round(2.0 / T)
    late = np.concatenate([z[:lag], z[:-lag]])
    lines = SeveralLines([(u, z, None), (u, late, None)], T, wf, fit, 0.0,
                         (true_h.penalty, np.nan), cfg.estimation, cfg.rounds)  # fmt: skip
    out, prof, kept = lines.rls(exact, true_h)
    assert not kept and out is exact and prof is true_h
    with pytest.raises(ValueError, match="rls_lines_passes"):
        IdentifyConfig().updated(rls_lines_passes=-1)


def test_threads_give_the_same_estimate_and_the_chains_run_their_last_stages():
    """``workers``: the candidates, then the batch chain beside the RLS chain (continuation,
    re-indexing rounds), on threads; every result equals the one computed in turn. The
    last stages (``SeveralLines.joint`` and ``.rls``) run on their chain's result, and the
    held-out scores are those of what they return."""
    wf, u, prof, z = _record()
    again = RLSSettings(alpha="unit", p0=0.1, passes=2, k0=3000, free=("c", "a", "w", "y0"))
    seen: dict[str, object] = {}

    def joint_hook(m, h):
        seen["batch"] = m
        return replace(m, offset_nm=m.offset_nm + 1.0), h

    def rls_hook(res, h):
        seen["rls"] = res
        return res, h

    kw = dict(orders=((5, 3), (5, 6)), rls_continue=again, rls_reindex_rounds=1,
              rls_reindex_passes=2, reindex_rounds=2, selection_rounds=1)  # fmt: skip
    serial = _estimate(wf, u, z, prof, 0.0, workers=1, **kw)
    threads = _estimate(wf, u, z, prof, 0.0, workers=4, **kw)
    assert threads.selection.trials == serial.selection.trials
    np.testing.assert_array_equal(threads.rls.theta, serial.rls.theta)
    assert threads.rls_round == serial.rls_round
    np.testing.assert_array_equal(threads.batch_model.weights, serial.batch_model.weights)
    assert threads.heldout_rms_nm == serial.heldout_rms_nm
    hooked = _estimate(wf, u, z, prof, 0.0, workers=2, joint=joint_hook, rls=rls_hook,
                       **kw)  # fmt: skip
    assert seen["rls"] is not None
    np.testing.assert_array_equal(seen["batch"].weights, serial.batch_model.weights)
    assert hooked.batch_model.offset_nm == pytest.approx(serial.batch_model.offset_nm + 1.0)
    assert hooked.heldout_rms_nm["batch"] != serial.heldout_rms_nm["batch"]
    assert hooked.heldout_rms_nm["rls"] == serial.heldout_rms_nm["rls"]
    # the final stages run after the held-out scoring: the scores are those before them
    final = _estimate(wf, u, z, prof, 0.0, workers=2, whole_batch=joint_hook,
                      whole_rls=rls_hook, **kw)  # fmt: skip
    assert final.heldout_rms_nm == serial.heldout_rms_nm
    assert final.batch_model.offset_nm == pytest.approx(serial.batch_model.offset_nm + 1.0)
    with pytest.raises(ValueError, match="workers"):
        _estimate(wf, u, z, prof, 0.0, workers=0)


def test_a_batch_chain_far_worse_than_the_rls_is_run_again_from_the_rls_estimate():
    """``batch_restart_ratio``: when the batch chain ends far worse than the RLS chain on the
    held-out heights (here made to by a last stage that spoils its first model), the chain
    is run again from the RLS estimate and the better of the two is kept; a chain that is
    not far worse is left alone, and ``None`` never restarts."""
    wf, u, prof, z = _record()
    calls: list[float] = []

    def spoil_first(m, h):
        calls.append(m.gain)
        return (replace(m, gain=1.3 * m.gain) if len(calls) == 1 else m), h

    plain = _estimate(wf, u, z, prof, 0.0, batch_restart_ratio=2.0)
    assert plain.batch_restart is None
    spoiled = _estimate(wf, u, z, prof, 0.0, joint=spoil_first, batch_restart_ratio=2.0)
    assert len(calls) == 2
    r = spoiled.batch_restart
    assert r is not None and r["kept"] == "restart"
    assert r["first"] > 2.0 * spoiled.heldout_rms_nm["rls"] and r["first"] > 1.0
    assert spoiled.heldout_rms_nm["batch"] == r["restart"] < 0.3
    assert spoiled.batch_model.gain == pytest.approx(TRUE.gain, rel=0.02)
    calls.clear()
    never = _estimate(wf, u, z, prof, 0.0, joint=spoil_first, batch_restart_ratio=None)
    assert len(calls) == 1 and never.batch_restart is None
    assert never.heldout_rms_nm["batch"] == pytest.approx(r["first"])
    for bad in (0.5, float("nan")):
        with pytest.raises(ValueError, match="batch_restart_ratio"):
            _estimate(wf, u, z, prof, 0.0, batch_restart_ratio=bad)


def test_the_fits_over_the_whole_record_fit_the_held_out_part_too():
    """``final_rounds`` / ``rls_final_passes``: after the held-out part has chosen the
    orders, the models are fitted over the whole record. From an exact model on the true
    ``h`` nothing moves far, the RLS traces cover the whole record, and 0 turns them off."""
    from piezocomp.identification.config import IdentifyConfig

    wf, u, true_h, z = _record()
    settings = RLSSettings(alpha="unit", p0=0.1, passes=2, k0=3000, free=("c", "a", "w", "y0"))
    cfg = IdentifyConfig().updated(rls_settings=settings, rls_continue=settings, final_rounds=1,
                           rls_final_passes=2, reindex_max_nfev=5,
                           creep_tau_range_s=(0.1, 500.0))  # fmt: skip
    n = u.size
    fit = np.ones(n, dtype=bool)
    line = SeveralLines([(u, z, None)], T, wf, fit, 0.0, (1e-6,), cfg.estimation, cfg.rounds)
    exact = rls(u[: n - n // 4], z[: n - n // 4], true_h, TRUE, T, settings=settings,
                state=record_state(TRUE, u[0], 0.0))  # fmt: skip
    res, prof = line.whole_rls(exact, true_h)
    assert res.error_nm.shape == (n,) and prof is not true_h
    held = np.zeros(n, dtype=bool)
    held[n - n // 4 :] = True
    assert heldout_rms(prof, res.model, u, z, T, held, 0.0) < 0.5
    model, prof_b = line.whole_batch(TRUE, true_h)
    assert heldout_rms(prof_b, model, u, z, T, held, 0.0) < 0.5
    off = cfg.updated(final_rounds=0, rls_final_passes=0)
    none = replace(line, rounds=off.rounds)
    assert none.whole_rls(exact, true_h) == (exact, true_h)
    assert none.whole_batch(TRUE, true_h) == (TRUE, true_h)
    for name in ("final_rounds", "rls_final_passes"):
        with pytest.raises(ValueError, match=name):
            IdentifyConfig().updated(**{name: -1})


def test_sensorless_config_checks_the_workers():
    import os

    from piezocomp.identification.config import IdentifyConfig

    assert 1 <= IdentifyConfig().estimation.workers_used <= min(4, os.cpu_count() or 1)
    assert IdentifyConfig().updated(workers=1).estimation.workers_used == 1
    for bad in (0, 2.0, True):
        with pytest.raises(ValueError, match="workers"):
            IdentifyConfig().updated(workers=bad)  # type: ignore[arg-type]


def test_sensorless_config_checks_the_batch_restart_and_says_what_it_did():
    from piezocomp.identification.config import IdentifyConfig
    from piezocomp.identification.estimation.chain import Estimation
    from piezocomp.identification.estimation.findings import BATCH_ASTRAY_RATIO, batch_restart_notes

    assert IdentifyConfig().estimation.batch_restart_ratio == BATCH_ASTRAY_RATIO
    assert IdentifyConfig().updated(batch_restart_ratio=None).estimation.batch_restart_ratio is None
    for bad in (0.9, float("inf"), True):
        with pytest.raises((ValueError, TypeError), match="batch_restart_ratio"):
            IdentifyConfig().updated(batch_restart_ratio=bad)  # type: ignore[arg-type]
    held = {"initial": 4.0, "rls": 0.71, "batch": 0.8}
    est = Estimation(None, None, None, None, held, None, None)  # type: ignore[arg-type]
    assert batch_restart_notes(est) == []
    for kept, says in (("restart", "(kept)"), ("first", "not kept")):
        r = {"first": 3.32, "restart": 0.8, "kept": kept}
        (text,) = batch_restart_notes(replace(est, batch_restart=r))
        assert "3.32" in text and "0.71" in text and "0.80" in text and says in text


def test_sensorless_config_checks_the_order_choice():
    from piezocomp.identification.config import IdentifyConfig

    for bad in (-0.1, float("nan"), True):
        with pytest.raises(ValueError, match="order_tolerance"):
            IdentifyConfig().updated(order_tolerance=bad)


def test_estimate_prefers_the_larger_orders_within_the_tolerance():
    """Within ``order_tolerance`` of the best held-out heights the candidate with the most
    parameters is chosen: the held-out heights cannot tell 16 play operators from 32 while
    the truth prefers 32 (docs/identification-design.md, "Orders and held-out heights")."""
    wf, u, prof, z = _record()
    kw = dict(orders=((5, 3), (5, 6)), refine_max_nfev=5)
    large = _estimate(wf, u, z, prof, 0.0, order_tolerance=10.0, **kw)
    assert large.selection.n_creep == 6 and large.batch_model.n_creep == 6
