import numpy as np
import pytest

from piezocomp.limits import CommandLimits


def test_range_refusal_names_the_sample_and_value():
    lim = CommandLimits.symmetric(1000.0)
    with pytest.raises(ValueError, match=r"command\[1\] = 600 nm is outside .*\[-500, 500\]"):
        lim.check([0.0, 600.0, 0.0], 0.01)


def test_clip_reports_every_sample():
    lim = CommandLimits(-1.0, 1.0)
    u, rep = lim.check([0.0, 2.0, -3.0, 0.5], 0.01, clip=True)
    np.testing.assert_array_equal(u, [0.0, 1.0, -1.0, 0.5])
    assert rep.range_clipped.tolist() == [1, 2] and rep.n_clipped == 2


def test_slew_includes_the_step_from_the_previous_command():
    lim = CommandLimits(-10.0, 10.0, max_slew_nm_per_s=100.0)  # 1 nm per 10 ms
    with pytest.raises(ValueError, match="step at sample 0"):
        lim.check([5.0], 0.01, previous_nm=0.0)
    u, rep = lim.check([5.0, 5.0], 0.01, previous_nm=0.0, clip=True)
    np.testing.assert_allclose(u, [1.0, 2.0])
    assert rep.slew_clipped.tolist() == [0, 1]


@pytest.mark.parametrize(
    ("args", "match"),
    [((1.0, 1.0), "min_nm must be < max_nm"), ((0.0, 1.0, 0.0), "max_slew_nm_per_s must be > 0")],
)
def test_bad_limits(args, match):
    with pytest.raises(ValueError, match=match):
        CommandLimits(*args)


def test_nan_commands_refused():
    with pytest.raises(ValueError, match="finite"):
        CommandLimits(-1.0, 1.0).check([0.0, np.nan], 0.01)
