"""The identification's plan of instrument time, and the budget that shortens it."""

import dataclasses

import pytest

from identify_configs import small
from piezocomp.identification.planning import BUDGET_STEPS, planned_instrument_s, within_budget
from piezocomp.virtual_afm import VirtualAFM


@pytest.fixture(scope="module")
def afm():
    return VirtualAFM.from_preset("cpr5-nodrift")


def default(afm):
    return small(span_nm=2000.0, calibrate="full-range").acquisition


def test_the_plan_adds_up_the_protocol(afm):
    """The overview is its lines at its line rate; the extra line repeats the overview, the
    settling and the record; the calibration cycles are there only when asked for."""
    cfg = default(afm)
    p = planned_instrument_s(afm, cfg, "x")
    assert p["overview"] == pytest.approx(128 * 2 * 2000.0 / 250.0)
    assert p["settling"] == pytest.approx(600.0, abs=16.0)  # whole cycles of 16 s
    assert p["extra lines"] > p["overview"] + p["settling"]
    lean = planned_instrument_s(afm, dataclasses.replace(cfg, calibrate="span",
                                                          extra_lines=0), "x")  # fmt: skip
    assert "calibration cycles" not in lean and lean["extra lines"] == 0.0


def full_config(afm):
    return small(span_nm=2000.0, calibrate="full-range")


def test_without_a_budget_the_configuration_runs_as_it_is(afm):
    cfg = full_config(afm)
    plan = within_budget(afm, cfg, ("x", "y"))
    assert plan.config == cfg and plan.steps == ()
    assert plan.total_s == pytest.approx(
        sum(sum(planned_instrument_s(afm, cfg.acquisition, ax).values()) for ax in "xy")
    )
    assert within_budget(afm, cfg, ("x", "y"), plan.total_s + 1.0).config == cfg


def test_a_budget_takes_the_steps_in_order_until_the_plan_fits(afm):
    cfg = full_config(afm)
    full = within_budget(afm, cfg, ("x", "y")).total_s
    seen = []
    for budget_min in (150, 90, 45, 30):
        plan = within_budget(afm, cfg, ("x", "y"), 60.0 * budget_min)
        assert plan.total_s <= 60.0 * budget_min < full
        assert plan.steps == tuple(name for name, _, _ in BUDGET_STEPS[: len(plan.steps)])
        seen.append(len(plan.steps))
        for _, field, value in BUDGET_STEPS[: len(plan.steps)]:
            assert getattr(plan.config.acquisition, field) == value
        # nothing else changes
        back = {f: getattr(cfg.acquisition, f) for _, f, _ in BUDGET_STEPS}
        assert plan.config.updated(**back) == cfg
    assert seen == sorted(seen) and seen[-1] > seen[0]
    assert "planned instrument time" in plan.describe() and BUDGET_STEPS[0][0] in plan.describe()
    assert "fails its own validation" in plan.describe()  # 30 min: more than one step
    one = within_budget(afm, cfg, ("x", "y"), 150 * 60.0)
    assert one.steps == (BUDGET_STEPS[0][0],) and "fails" not in one.describe()


def test_a_step_never_lengthens_what_is_already_shorter(afm):
    cfg = full_config(afm).updated(overview_speed_nm_per_s=4000.0, extra_lines=0)
    plan = within_budget(afm, cfg, ("x",), 60.0 * 12)
    acq = plan.config.acquisition
    assert acq.overview_speed_nm_per_s == 4000.0 and acq.extra_lines == 0
    assert "no extra line" not in plan.steps and "overviews at 1 um/s" not in plan.steps


def test_a_budget_below_the_shortest_protocol_is_refused_in_one_line(afm):
    with pytest.raises(ValueError, match=r"a budget of 3 min is below the shortest") as exc:
        within_budget(afm, full_config(afm), ("x", "y"), 180.0)
    assert "\n" not in str(exc.value)
    for bad in (0.0, -60.0, float("nan")):
        with pytest.raises(ValueError, match="positive number of seconds"):
            within_budget(afm, full_config(afm), ("x",), bad)


def test_an_instrument_that_states_no_calibration_scan_is_planned_at_the_default_speed(afm):
    """A controller without ``calibration_scan`` (the Nanonis driver): the calibration
    cycles are planned at the speed they will run at, the default one."""
    from piezocomp.identification.acquisition.recording import DEFAULT_CALIBRATION_SPEED_NM_PER_S

    class Bare:
        sample_period_s = afm.sample_period_s
        range_nm = afm.range_nm
        max_speed_nm_per_s = afm.max_speed_nm_per_s

    cfg = default(afm)
    p = planned_instrument_s(Bare(), cfg, "x")
    span = cfg.calibration_span_nm(afm.range_nm)
    cycles = 2 * cfg.waveform.n_steady * span / DEFAULT_CALIBRATION_SPEED_NM_PER_S
    assert cycles <= p["calibration cycles"] <= cycles * 1.3  # part B: one more cycle


def test_a_step_that_saves_nothing_is_not_taken(afm):
    """At a waveform speed of 2 um/s the overviews already run faster than the step's
    1 um/s: the step is not reported, and a refusal with no step taken reads cleanly."""
    cfg = full_config(afm).updated(speed_nm_per_s=2000.0, extra_lines=0, overview_pixels=64,
                            line_settle_s=60.0)  # fmt: skip
    with pytest.raises(ValueError, match=r"planned \d+ min for 1 axis\(es\); give") as exc:
        within_budget(afm, cfg, ("x",), 60.0)
    assert "overviews at 1 um/s" not in str(exc.value) and "()" not in str(exc.value)


def test_a_span_whose_extra_line_cannot_fit_is_refused_before_anything_moves(afm):
    """cpr5's range is 5000 nm: the extra line's overview (a square of the span, 1000 nm
    along the slow axis) fits up to a 3000 nm span; at 4000 nm the identification ran on its
    first line alone and refused its own model (the issue's case), so the plan refuses it in
    one line naming the largest span that fits; without an extra line it is planned."""
    big = dataclasses.replace(default(afm), span_nm=4000.0)
    with pytest.raises(ValueError, match="the largest span whose extra line fits is 3000 nm"):
        planned_instrument_s(afm, big, "x")
    with pytest.raises(ValueError, match="span_nm = 4000 nm"):
        within_budget(afm, small(span_nm=4000.0, calibrate="full-range"), ("y",))
    planned_instrument_s(afm, dataclasses.replace(big, span_nm=3000.0), "y")  # fits exactly
    planned_instrument_s(afm, dataclasses.replace(big, extra_lines=0), "x")
    off = dataclasses.replace(big, span_nm=3000.0, center_nm=(0.0, 100.0))
    planned_instrument_s(afm, off, "x")  # the other side still fits: -900 +- 1500 nm
