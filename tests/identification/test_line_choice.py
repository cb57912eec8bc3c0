"""Choice of the identification line from an overview image (Section V, step 1)."""

from __future__ import annotations

import numpy as np
import pytest

from piezocomp.identification.acquisition.line_choice import choose_line
from piezocomp.instrument import ScanImage


def _image(
    rows_particles: dict[int, list[float]], shift_nm: float = 20.0, n: int = 200
) -> ScanImage:
    """Rows of a 1000 nm overview with Gaussian particles at given x; the backward trace
    sees each particle ``shift_nm`` earlier (hysteresis)."""
    x = np.linspace(-500, 500, n)
    fwd = np.zeros((40, n))
    bwd = np.zeros((40, n))
    rng = np.random.default_rng(0)
    for row, xs in rows_particles.items():
        for xp in xs:
            fwd[row] += 15 * np.exp(-0.5 * ((x - xp) / 8) ** 2)
            bwd[row] += 15 * np.exp(-0.5 * ((x - xp + shift_nm) / 8) ** 2)
    fwd += 0.1 * rng.standard_normal(fwd.shape)
    bwd += 0.1 * rng.standard_normal(bwd.shape)
    return ScanImage(fwd, bwd, x, np.linspace(-500, 500, 40), 1.0)


def test_chooses_the_row_with_most_particles():
    rows = {
        3: [-400, -200, 0, 200, 400],  # 5: not enough for degree 5
        10: [-450, -300, -150, 0, 150, 300, 450],  # 7 spread over the line: chosen
        20: [-100, -60, -20, 20, 60, 100, 140, 180],  # 8 but bunched in the middle
    }
    line = choose_line(_image(rows), degree=5)
    assert line.index == 10 and line.n_particles == 7
    assert line.slow_nm == pytest.approx(np.linspace(-500, 500, 40)[10])
    np.testing.assert_allclose(line.positions_nm, rows[10], atol=6.0)
    assert line.counts[3] == 5 and line.counts[20] == 8
    # with the coverage rule relaxed, the bunched row wins on its count
    assert choose_line(_image(rows), degree=5, min_coverage=0.2).index == 20


def test_refuses_with_the_count_and_the_rule():
    rows = {7: [-400, -200, 0, 200, 400]}
    with pytest.raises(ValueError, match=r"more than degree = 5 particles.*crosses 5"):
        choose_line(_image(rows), degree=5)


def test_columns_for_the_y_axis():
    img = _image({12: [-450, -300, -150, 0, 150, 300, 450]}, shift_nm=0.0)
    t = ScanImage(img.forward_nm.T.copy(), img.backward_nm.T.copy(), img.y_nm, img.x_nm, 1.0)
    line = choose_line(t, degree=5, axis="y")
    assert line.axis == "y" and line.index == 12


def test_checks():
    img = _image({})
    with pytest.raises(ValueError, match="axis"):
        choose_line(img, axis="z")
    with pytest.raises(TypeError, match="ScanImage"):
        choose_line(np.zeros((3, 3)))  # type: ignore[arg-type]
