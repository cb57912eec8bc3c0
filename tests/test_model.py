import numpy as np
import pytest
from hypothesis import given

from piezocomp.model import ModelState, ScannerModel, ScannerModel2D, simulate
from piezocomp.testing import reference
from strategies import T, models, trajectories


def _ref(model, u, state=None):
    kw = {}
    if state is not None:
        kw = {"z0": state.play_nm, "x0": state.creep_nm, "u_prev": state.u_prev_nm}
    return reference.forward(
        u,
        model.offset_nm,
        model.gain,
        model.thresholds_nm,
        model.weights,
        model.creep_time_constants_s,
        model.creep_gains,
        T,
        **kw,
    )


@given(models(), trajectories())
def test_forward_matches_reference(model, u):
    y, _ = simulate(model, u, T)
    np.testing.assert_allclose(y, _ref(model, u), rtol=1e-12, atol=1e-9)


@given(models(), trajectories(min_size=3), trajectories(max_size=50))
def test_batch_equals_chunked_equals_per_sample(model, u, history):
    _, start = simulate(model, history, T)  # a non-zero starting state
    y, end = simulate(model, u, T, start)
    cut = len(u) // 3
    y1, s1 = simulate(model, u[:cut], T, start)
    y2, s2 = simulate(model, u[cut:], T, s1)
    np.testing.assert_array_equal(np.concatenate([y1, y2]), y)
    assert s2 == end
    state, per_sample = start, []
    for uk in u:
        yk, state = simulate(model, [uk], T, state)
        per_sample.append(yk[0])
    np.testing.assert_array_equal(per_sample, y)
    assert state == end


def test_one_model_serves_any_sample_rate():
    """The pole comes from the time constant: a step's creep at 1 s is the same at 1 or 10 ms."""
    m = ScannerModel(gain=0.8, creep_time_constants_s=[0.3, 4.0], creep_gains=[0.1, 0.05])
    y_fast, _ = simulate(m, np.ones(1001), 0.001)
    y_slow, _ = simulate(m, np.ones(101), 0.01)
    assert y_fast[1000] == pytest.approx(y_slow[100], rel=1e-12)


def test_loading_curve_is_eq8():
    m = ScannerModel(gain=0.5, thresholds_nm=[10.0, 30.0], weights=[0.2, 0.1])
    r = np.array([0.0, 5.0, 10.0, 20.0, 30.0, 40.0])
    expected = [0.0, 2.5, 5.0, 5.0 + 0.7 * 10, 12.0 + 0.7 * 10, 19.0 + 0.8 * 10]
    np.testing.assert_allclose(m.loading_curve(r), expected)
    # the loading curve is what the PI part traces from zero state on a rising input
    y, _ = simulate(m, r, T)
    np.testing.assert_allclose(y, expected)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"gain": 0.0}, r"gain must be > 0.*Got 0.0"),
        ({"gain": np.nan}, "gain must be finite"),
        ({"thresholds_nm": [1.0, 2.0], "weights": [0.1, 0.0]}, r"weights\[1\] = 0.0"),
        ({"thresholds_nm": [1.0, 2.0], "weights": [0.1, -0.2]}, "weights must be > 0"),
        ({"thresholds_nm": [2.0, 1.0], "weights": [0.1, 0.1]}, "strictly increasing"),
        ({"thresholds_nm": [0.0, 1.0], "weights": [0.1, 0.1]}, "thresholds_nm must be > 0"),
        ({"thresholds_nm": [1.0], "weights": [0.1, 0.1]}, "one entry per threshold"),
        (
            {"creep_time_constants_s": [1.0], "creep_gains": [-0.1]},
            r"creep_gains must be >= 0.*-0.1",
        ),
        ({"creep_time_constants_s": [0.0], "creep_gains": [0.1]}, "time_constants_s must be > 0"),
        ({"offset_nm": np.inf}, "offset_nm must be finite"),
    ],
)
def test_non_invertible_models_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ScannerModel(**kwargs)


def test_parameters_are_frozen_and_copied():
    w = np.array([0.1, 0.2])
    m = ScannerModel(thresholds_nm=[1.0, 2.0], weights=w)
    w[0] = 5.0
    assert m.weights[0] == 0.1
    with pytest.raises(ValueError):
        m.weights[0] = 1.0
    with pytest.raises(AttributeError):
        m.gain = 2.0  # type: ignore[misc]


def test_nan_trajectory_and_wrong_state_are_refused():
    m = ScannerModel(thresholds_nm=[1.0], weights=[0.1])
    with pytest.raises(ValueError, match=r"u_nm must contain only finite samples.*index 2"):
        simulate(m, [0.0, 1.0, np.nan], T)
    with pytest.raises(ValueError, match="play and"):
        simulate(m, [0.0], T, ModelState(np.zeros(3), np.zeros(0)))


def test_model_2d_axes():
    mx, my = ScannerModel(gain=1.0), ScannerModel(gain=2.0)
    m = ScannerModel2D(mx, my)
    assert m["x"] is mx and m["y"] is my
    with pytest.raises(TypeError, match="y must be a ScannerModel"):
        ScannerModel2D(mx, None)  # type: ignore[arg-type]
