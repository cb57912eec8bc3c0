"""Frames of the position: a model put back on the loop's span (Section IV)."""

import numpy as np
import pytest

from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.identification.reference.frames import span_frame

LOOP = SymmetricLoop(np.array([-0.01, 0.96, 0.03, 0.05, -0.02, 0.01]) / 0.99, -500.0, 500.0)


@pytest.mark.parametrize(("scale", "shift"), [(2.06, -40.0), (0.8, 12.0), (1.0, 0.0)])
def test_span_frame_undoes_a_scale_and_shift_of_the_loops_trace(scale, shift):
    """Mathematics only: a trace that is the loop's ascending branch stretched and shifted
    (a model drifted in its own frame) is mapped back onto the branch exactly."""
    u = np.linspace(-500.0, 500.0, 301)
    y = scale * LOOP.ascending(u) + shift
    a, b = span_frame(LOOP, u, y)
    assert a == pytest.approx(1.0 / scale, rel=1e-12)
    np.testing.assert_allclose(a * y + b, LOOP.ascending(u), atol=1e-9)


def test_span_frame_keeps_the_spans_ends_for_any_trace_shape():
    """The condition fixes the two ends (span and middle), not the shape between them."""
    u = np.linspace(-500.0, 500.0, 201)
    y = 1.7 * u + 30.0 * np.sin(np.pi * u / 1000.0) ** 2
    a, b = span_frame(LOOP, u, y)
    ends = LOOP.ascending(np.array([-500.0, 500.0]))
    np.testing.assert_allclose(a * y[[0, -1]] + b, ends, atol=1e-9)


def test_span_frame_refuses_a_trace_that_does_not_advance_or_does_not_fit():
    u = np.linspace(-500.0, 500.0, 11)
    with pytest.raises(ValueError, match=r"must advance over the span; it moves -1e\+03 nm"):
        span_frame(LOOP, u, -u)
    with pytest.raises(ValueError, match=r"must advance over the span; it moves nan nm"):
        span_frame(LOOP, u, np.r_[u[:-1], np.nan])
    with pytest.raises(ValueError, match=r"same length >= 2\. Got shapes \(11,\) and \(10,\)"):
        span_frame(LOOP, u, u[:-1])
