"""Drift measured on an image series, and the ``piezocomp drift`` command."""

import json

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.drift.series import measure_series, track_series
from piezocomp.instrument import ScanImage

SIDE, PIX, LINE_S = 600.0, 64, 0.5


def _particles(seed=3, n=160, extent=1400.0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-extent / 2, extent / 2, (n, 2))


def frame(shift, t_start, particles, noise=0.0, rng=None):
    """An image of Gaussian particles whose content lies ``shift`` from where it is at 0:
    a drift the filter did not generate (a ramp with a wobble, below)."""
    x = np.linspace(-SIDE / 2, SIDE / 2, PIX)
    X, Y = np.meshgrid(x, x)
    z = np.zeros_like(X)
    for px, py in particles + np.asarray(shift):
        z += 12.0 * np.exp(-((X - px) ** 2 + (Y - py) ** 2) / (2 * 9.0**2))
    if noise:
        z = z + rng.normal(0.0, noise, z.shape)
    return ScanImage(z, z, x, x, LINE_S, t_start)


def drift_path(t):
    return np.column_stack([0.2 * t + 3.0 * np.sin(t / 150.0), -0.05 * t])


def test_a_drift_of_more_than_a_third_of_the_image_is_followed_to_a_fraction_of_a_nm():
    """0.2 nm/s for 19 minutes moves the content 230 nm, more than a third of the 600 nm
    frame (beyond which one registration refuses): the reference frame moves on, and the
    shifts stay within a fraction of a nanometre of the true ones."""
    p = _particles()
    t0 = np.arange(20) * 60.0
    t_mid = t0 + 0.5 * PIX * LINE_S
    true = drift_path(t_mid) - drift_path(t_mid[:1])
    images = [frame(d, t, p) for d, t in zip(true, t0, strict=True)]
    kept, shifts, errors, refused = measure_series(images)
    assert np.all(errors[1:] < 0.2)  # noise-free frames match closely
    assert kept == list(range(20)) and not refused
    assert np.max(np.abs(true[:, 0])) > SIDE / 3
    assert np.max(np.hypot(*(shifts - true).T)) < 0.5
    series = track_series(images)
    assert series.noise_fitted and series.frames == tuple(range(20))
    np.testing.assert_allclose(series.t_s, t_mid, atol=0.01)  # the frames' middles
    assert np.max(np.hypot(*(series.filtered_nm - true).T)) < 0.5
    assert series.rate_nm_per_s == pytest.approx(np.hypot(*(true[-1] / (t_mid[-1] - t_mid[0]))),
                                                 rel=0.02)  # fmt: skip
    # the drift rate at the end is the path's (its wobble included), within a few %
    v_true = np.array([0.2 + 3.0 / 150.0 * np.cos(t_mid[-1] / 150.0), -0.05])
    assert np.allclose(series.velocity_nm_per_s[-1], v_true, atol=0.02)


def test_a_frame_that_does_not_register_is_left_out_and_said():
    p = _particles()
    t0 = np.arange(6) * 60.0
    images = [frame((0.1 * t, 0.0), t, p) for t in t0]
    blank = np.zeros((PIX, PIX))
    x = images[0].x_nm
    images[3] = ScanImage(blank, blank, x, x, LINE_S, t0[3])
    series = track_series(images)
    assert series.frames == (0, 1, 2, 4, 5)
    assert len(series.refused) == 1 and series.refused[0][0] == 3
    assert not series.noise_fitted  # 5 frames: too few to estimate the noise


def test_bad_series_are_refused_with_the_rule():
    p = _particles()
    one = frame((0.0, 0.0), 0.0, p)
    with pytest.raises(ValueError, match="at least 2 frames"):
        measure_series([one])
    x = np.linspace(0, 100, 32)
    small = ScanImage(np.zeros((32, 32)), np.zeros((32, 32)), x, x, LINE_S, 60.0)
    with pytest.raises(ValueError, match="same grid"):
        measure_series([one, small])
    with pytest.raises(ValueError, match="frame times must increase"):
        track_series([one, frame((1.0, 0.0), 0.0, p)])


def test_the_command_on_a_short_virtual_movie(tmp_path, capsys):
    """``piezocomp drift`` on the drifting virtual AFM's raw scanner: every output is
    written, a series too short to estimate the noise says so, and so does the note that a
    raw scanner's shifts are not in true nm."""
    out = tmp_path / "d"
    code = main(["drift", "--preset", "cpr5", "--frames", "4", "--pixels", "32",
                 "--size-nm", "400", "--line-rate-hz", "4", "--interval-s", "20",
                 "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 4 and s["registered"] == 4 and not s["noise_fitted"]
    assert any("fewer than 10" in f for f in s["findings"])
    assert any("raw scanner" in f for f in s["findings"])
    assert (out / "drift.png").stat().st_size > 0
    header = (out / "drift.csv").read_text().splitlines()[0]
    assert header.startswith("t_s,measured_x_nm") and "true_x_nm" in header


def test_the_command_on_files_needs_their_times(tmp_path, capsys):
    from piezocomp.io.afm_files import write_gwy
    from piezocomp.io.afm_scan import AfmScan

    p = _particles()
    files = []
    for k in range(3):
        im = frame((2.0 * k, 0.0), 60.0 * k, p)
        path = tmp_path / f"f{k}.gwy"
        write_gwy(path, AfmScan(im.forward_nm, im.backward_nm, (SIDE, SIDE)))
        files.append(str(path))
    assert main(["drift", "--scans", *files, "--out", str(tmp_path / "a")]) == 2
    assert "--interval-s is needed" in capsys.readouterr().err
    assert main(["drift", "--scans", *files, "--interval-s", "60",
                 "--out", str(tmp_path / "b")]) == 0  # fmt: skip
    s = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert s["registered"] == 3
    # 4 nm of content shift (the file's pixels are side / n, the frame's side / (n - 1))
    assert s["drift_end_nm"][0] == pytest.approx(4.0, abs=0.2)


def test_the_command_refuses_what_does_not_apply(tmp_path, capsys):
    base = ["drift", "--out", str(tmp_path / "x")]
    for extra, text in (
        (["--scans", "a.gwy", "--frames", "5"], "--frames: movie option"),
        (["--scans", "a.gwy", "--max-speed-nm-per-s", "5"], "goes with --instrument"),
        (["--preset", "cpr5", "--channel", "height"], "--channel: an option of --scans"),
        (["--preset", "cpr5", "--interval-s", "nan"], "--interval-s must be a finite"),
        (["--preset", "cpr5", "--pixels", "4"], "--pixels must be >= 8. Got 4"),
    ):
        assert main([*base, *extra]) == 2
        assert text in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
