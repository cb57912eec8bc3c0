"""Checking pushes from the particles of two images: placed, stuck, off target, vanished."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezocomp.positioning.push_check import (
    PushCheck,
    PushedParticle,
    check_pushes,
    count_failures,
    with_action,
)

BEFORE = np.array([[0.0, 0.0], [200.0, 0.0], [0.0, 200.0], [200.0, 200.0], [-200.0, -200.0]])
PUSHED = [
    PushedParticle(0, 0, (100.0, 0.0)),
    PushedParticle(1, 1, (100.0, 50.0)),
    PushedParticle(2, 2, (100.0, 100.0)),
    PushedParticle(3, 3, (100.0, 150.0)),
]


def _after(shift=(0.0, 0.0)):
    after = np.array([
        [100.4, 0.3],  # 0 arrived
        [200.2, -0.1],  # 1 did not move
        [60.0, 170.0],  # 2 left its line half way, off it
        # 3 is gone
        [-200.1, -199.8],  # 4 was not pushed
    ])  # fmt: skip
    return after + np.asarray(shift)


@pytest.mark.parametrize("shift", [(0.0, 0.0), (23.0, -17.0)])
def test_each_way_a_push_ends_is_told_apart_whatever_the_frames_shift(shift):
    checks, found_shift = check_pushes(BEFORE, PUSHED, _after(shift), check_nm=5.0)
    assert [c.kind for c in checks] == ["placed", "stuck", "off_target", "vanished"]
    assert [c.target for c in checks] == [0, 1, 2, 3]
    assert_allclose(found_shift, shift, atol=0.5)
    assert_allclose(checks[2].found_nm, np.array([60.0, 170.0]) + shift)
    assert checks[3].found_nm is None
    assert [c.failed for c in checks] == [False, True, True, True]


def test_a_push_barely_longer_than_the_check_that_left_its_particle_is_stuck():
    before = np.array([[0.0, 0.0], [300.0, 300.0]])
    pushed = [PushedParticle(0, 0, (8.0, 0.0))]
    checks, _ = check_pushes(before, pushed, np.array([[0.1, 0.0], [300.0, 300.0]]))
    assert checks[0].kind == "stuck"
    checks, _ = check_pushes(before, pushed, np.array([[7.9, 0.1], [300.0, 300.0]]))
    assert checks[0].kind == "placed"


def test_a_fine_correction_that_did_not_move_its_particle_is_left_to_the_next_pass():
    """Shorter than check_nm, a push cannot be told from one that did not move: placed."""
    before = np.array([[0.0, 0.0], [300.0, 300.0]])
    pushed = [PushedParticle(0, 0, (1.5, 0.0))]
    checks, _ = check_pushes(before, pushed, np.array([[0.1, 0.0], [300.0, 300.0]]))
    assert checks[0].kind == "placed"


def test_an_unexpected_particle_far_from_the_push_is_not_taken_for_it():
    before = np.array([[0.0, 0.0], [300.0, 300.0]])
    pushed = [PushedParticle(0, 0, (100.0, 0.0))]
    after = np.array([[300.0, 300.0], [-400.0, 400.0]])  # a stranger, 400 nm away
    checks, _ = check_pushes(before, pushed, after)
    assert checks[0].kind == "vanished"


def test_what_the_next_pass_does_is_recorded_with_each_failure():
    stuck = PushCheck(0, "stuck", (0.0, 0.0), (100.0, 0.0), (0.0, 0.0))
    pos = np.array([[0.2, 0.0], [50.0, 50.0]])

    class P:
        def __init__(self, particle):
            self.particle = particle

    assert with_action(stuck, pos, np.array([0]), [P(0)], 5.0).action == "pushed_again"
    assert with_action(stuck, pos, np.array([1]), [P(1)], 5.0).action == "another_particle"
    assert with_action(stuck, pos, np.array([0]), [], 5.0).action == "none"
    placed = PushCheck(0, "placed", (0.0, 0.0), (100.0, 0.0), (100.0, 0.0))
    assert with_action(placed, pos, np.array([0]), [P(0)], 5.0).action == ""


def test_a_particles_failed_pushes_are_counted_as_it_moves_from_image_to_image():
    stuck = PushCheck(0, "stuck", (10.0, 5.0), (100.0, 0.0), (10.0, 5.0))
    once = count_failures([], [stuck], np.zeros(2), 5.0)
    assert [n for _, n in once] == [1]
    # the frame moved by (3, 4); pushed from there again, it went off target: two failures
    off = PushCheck(0, "off_target", (10.2, 5.1), (100.0, 0.0), (63.0, 29.0))
    twice = count_failures(once, [off], np.array([3.0, 4.0]), 5.0)
    assert [n for _, n in twice] == [2]
    assert_allclose(twice[0][0], [63.0, 29.0])
    # a place not pushed from moves with the frame; one pushed from and placed is forgotten
    other = PushCheck(1, "placed", (300.0, 0.0), (0.0, 0.0), (0.1, 0.0))
    kept = count_failures(once, [other], np.array([3.0, 4.0]), 5.0)
    assert len(kept) == 1
    assert_allclose(kept[0][0], [13.0, 9.0])
    placed = PushCheck(0, "placed", (10.0, 5.0), (100.0, 0.0), (100.2, 0.0))
    assert count_failures(once, [placed], np.zeros(2), 5.0) == []


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="check_nm must be > 0"):
        check_pushes(BEFORE, PUSHED, _after(), check_nm=0.0)
    with pytest.raises(ValueError, match="pushed particle 9"):
        check_pushes(BEFORE, [PushedParticle(9, 0, (0.0, 0.0))], _after())
