"""Property-based fuzzing of the command line: arguments and file contents drawn by
Hypothesis. Whatever comes in, a command exits 0, 1 or 2; an error is one line on stderr;
nothing hangs (every call is bounded in time); and an exit 0 is a right answer (checked
where the answer can be checked: the inverse and forward models on the files written)."""

from __future__ import annotations

import contextlib
import math
import signal
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from piezocomp.cli import main
from piezocomp.commands._common import read_columns
from piezocomp.io.model_files import load_model, save_model
from piezocomp.model import ScannerModel, ScannerModel2D, simulate

LIMIT_S = 20
"""Longest a fuzzed call may run before it counts as a hang."""

FUZZ = settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

NASTY = ["0", "-1", "1e300", "-1e300", "1e12", "1e-12", "nan", "inf", "-inf", "abc"]


def number(lo: float, hi: float, default: str) -> st.SearchStrategy[str]:
    """Mostly a sensible value (so that successes are checked), sometimes a nasty one."""
    return st.one_of(
        st.just(default), st.floats(lo, hi, allow_nan=False).map(repr), st.sampled_from(NASTY)
    )


nasty_int = st.one_of(
    st.sampled_from(["0", "-5", "1", "2", "10**6", "1000000000000", "3.5", "x"]),
    st.integers(-3, 300).map(str),
)


@contextlib.contextmanager
def time_limit(seconds: int) -> Iterator[None]:
    def boom(signum, frame):  # pragma: no cover - only on a hang
        raise TimeoutError(f"a command ran longer than {seconds} s")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def run(argv: list[str], capsys) -> tuple[int, str]:
    capsys.readouterr()
    with time_limit(LIMIT_S):
        code = main(argv)
    err = capsys.readouterr().err
    event(f"{argv[0]} exit {code}")
    if code == 2:
        event(f"{argv[0]}: " + err.split("error: ")[-1][:60])
    assert code in (0, 1, 2), (argv, code)
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("piezocomp"), (argv, err)
        assert "Traceback" not in err
    return code, err


def model_1d(**kw):
    return ScannerModel(
        offset_nm=1.0, gain=0.6, thresholds_nm=[15.0, 60.0, 200.0], weights=[0.05, 0.04, 0.03],
        creep_time_constants_s=[0.3, 30.0], creep_gains=[0.02, 0.05], **kw,
    )  # fmt: skip


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz_models")
    paths = {
        "1d": d / "m1.json",
        "1d_norange": d / "m0.json",
        "2d": d / "m2.json",
    }
    save_model(paths["1d"], model_1d(range_nm=5000.0, domain_nm=(-600.0, 600.0)))
    save_model(paths["1d_norange"], model_1d())
    m = model_1d(range_nm=5000.0)
    save_model(paths["2d"], ScannerModel2D(m, m))
    return paths


COLUMN_SETS = [
    ["t_s", "position_nm"], ["t_s", "x_nm"], ["t_s", "y_nm"], ["t_s", "x_nm", "y_nm"],
    ["t_s", "u_nm"], ["t_s", "ux_nm"], ["t_s", "uy_nm"], ["t_s", "ux_nm", "uy_nm"],
]  # fmt: skip
messy_columns = st.lists(
    st.sampled_from(["t_s", "x_nm", "y_nm", "position_nm", "u_nm", "ux_nm", "uy_nm", "z"]),
    min_size=1, max_size=4,
)  # fmt: skip
good_cell = st.floats(-400, 400, allow_nan=False)
bad_cell = st.sampled_from([float("nan"), float("inf"), 1e300, -1e300, 3000.0])


def _csv(names: list[str], rows: list[list[str]]) -> str:
    return "\n".join([",".join(names), *(",".join(r) for r in rows)]) + "\n"


@st.composite
def good_csv(draw, names: list[str]) -> str:
    """A well-formed trajectory file with these columns (successes are checked)."""
    n = draw(st.integers(2, 40))
    period = draw(st.sampled_from([0.008, 0.002, 1.0]))
    return _csv(names, [[repr(k * period)] + [repr(draw(good_cell)) for _ in names[1:]]
                        for k in range(n)])  # fmt: skip


@st.composite
def messy_csv(draw) -> str:
    """A trajectory file with faults drawn in: odd columns, bad cells, truncated lines,
    uneven stamps, no rows."""
    names = draw(st.one_of(st.sampled_from(COLUMN_SETS), messy_columns))
    n = draw(st.integers(0, 30))
    period = draw(st.sampled_from([0.008, 1e-6, 1.0]))
    jitter = draw(st.sampled_from([0.0, 1e-9, 0.3]))
    rows = []
    for k in range(n):
        vals = [repr(k * period + jitter * period * (k % 3 == 1)) if c == "t_s"
                else repr(draw(st.one_of(good_cell, bad_cell))) for c in names]  # fmt: skip
        if draw(st.integers(0, 10)) == 0:
            vals = vals[:-1]
        rows.append(vals)
    return _csv(names, rows)


def _run_trajectory(cmd, d, models, which, text, axis, extra, capsys):
    (d / "in.csv").write_text(text)
    argv = [cmd, "--model", str(models[which]), "--input", str(d / "in.csv"),
            "--output", str(d / "out.csv")]  # fmt: skip
    if axis:
        argv += ["--axis", axis]
    for e in extra:
        argv += e
    code, _ = run(argv, capsys)
    if code != 0:
        assert not (d / "out.csv").exists()
    return code, argv


@FUZZ
@given(text=messy_csv(), which=st.sampled_from(["1d", "1d_norange", "2d"]),
       axis=st.sampled_from([None, "x", "y"]),
       cmd=st.sampled_from(["compensate", "simulate"]),
       extra=st.lists(st.sampled_from([["--clip"], ["--range-nm", "-3"], ["--range-nm", "1e-9"],
                                        ["--allow-extrapolation"], ["--state-in", "nope.json"]]),
                      max_size=2))  # fmt: skip
def test_messy_trajectories_give_one_line_errors(tmp_path_factory, models, capsys, text, which,
                                                 axis, cmd, extra):  # fmt: skip
    if cmd == "simulate":
        extra = [e for e in extra if e[0] in ("--range-nm", "--state-in")]
    _run_trajectory(cmd, tmp_path_factory.mktemp("m"), models, which, text, axis, extra, capsys)


@st.composite
def compensate_case(draw):
    which = draw(st.sampled_from(["1d", "2d"]))
    if which == "1d":
        names = draw(st.sampled_from([["t_s", "position_nm"], ["t_s", "x_nm"], ["t_s", "y_nm"]]))
        axis = None
    else:
        names = draw(st.sampled_from([["t_s", "x_nm"], ["t_s", "y_nm"], ["t_s", "x_nm", "y_nm"]]))
        axis = draw(st.sampled_from([None, *(n[0] for n in names[1:])]))
    extra = draw(
        st.lists(
            st.sampled_from(
                [
                    ["--clip"],
                    ["--range-nm", "1000"],
                    ["--allow-extrapolation"],
                    ["--max-slew-nm-per-s", "5e4"],
                ]
            ),
            max_size=2,
        )
    )
    return which, draw(good_csv(names)), axis, extra  # fmt: skip


@FUZZ
@given(case=compensate_case())
def test_compensate_never_lies(tmp_path_factory, models, capsys, case):
    which, text, axis, extra = case
    d = tmp_path_factory.mktemp("c")
    code, argv = _run_trajectory("compensate", d, models, which, text, axis, extra, capsys)
    if code != 0:
        return
    model = load_model(models[which])
    data = np.genfromtxt(d / "out.csv", delimiter=",", names=True, ndmin=1)
    desired = np.genfromtxt(d / "in.csv", delimiter=",", names=True, ndmin=1)
    T = float(np.mean(np.diff(desired["t_s"])))
    half = 500.0 if "1000" in argv else 2500.0
    for name in data.dtype.names[1:]:
        u = np.asarray(data[name], dtype=float)
        assert np.all(np.isfinite(u)) and np.max(np.abs(u)) <= half + 1e-9
        if "--clip" in argv:
            continue  # clipped commands do not reach the trajectory, by design
        ax_model = model if isinstance(model, ScannerModel) else model[name[1]]
        pos = name[1:] if name != "u_nm" else next(
            c for c in ("x_nm", "y_nm", "position_nm") if c in desired.dtype.names
        )  # fmt: skip
        y, _ = simulate(ax_model, u, T)
        np.testing.assert_allclose(y, desired[pos], atol=1e-6 * (1 + np.max(np.abs(y))))


@st.composite
def simulate_case(draw):
    which = draw(st.sampled_from(["1d", "2d"]))
    names = [["t_s", "u_nm"]] if which == "1d" else [["t_s", "ux_nm"], ["t_s", "uy_nm"],
                                                    ["t_s", "ux_nm", "uy_nm"]]  # fmt: skip
    return (
        which,
        draw(good_csv(draw(st.sampled_from(names)))),
        draw(st.sampled_from([None, "5000", "600"])),
    )


@FUZZ
@given(case=simulate_case())
def test_simulate_never_lies(tmp_path_factory, models, capsys, case):
    which, text, range_nm = case
    d = tmp_path_factory.mktemp("s")
    extra = [["--range-nm", range_nm]] if range_nm else []
    code, _ = _run_trajectory("simulate", d, models, which, text, None, extra, capsys)
    if code != 0:
        return
    out = np.genfromtxt(d / "out.csv", delimiter=",", names=True, ndmin=1)
    cmd = np.genfromtxt(d / "in.csv", delimiter=",", names=True, ndmin=1)
    T = float(np.mean(np.diff(cmd["t_s"])))
    model = load_model(models[which])
    for name in out.dtype.names[1:]:
        src = "u_nm" if name == "position_nm" else f"u{name[0]}_nm"
        ax_model = model if isinstance(model, ScannerModel) else model[name[0]]
        np.testing.assert_allclose(out[name], simulate(ax_model, cmd[src], T)[0], atol=1e-6)


@st.composite
def waveform_args(draw) -> list[str]:
    """Half the time a sensible waveform (its file is checked), else anything."""
    sensible = draw(st.booleans())

    def pick(lo: float, hi: float, default: str) -> str:
        if sensible:
            return repr(draw(st.floats(lo, hi, allow_nan=False)))
        return draw(number(lo, hi, default))

    return [
        "--span-nm", pick(200, 2000, "1000"), "--speed-nm-per-s", pick(100, 1000, "250"),
        "--sample-period-s", pick(0.002, 0.02, "0.008"), "--center-nm", pick(-500, 500, "0"),
        "--n-random", draw(st.one_of(st.just("4"), nasty_int)) if not sensible else "4",
        "--max-dwell-s", pick(0, 2, "1"), "--n-decaying", "4",
    ]  # fmt: skip


@FUZZ
@given(args=waveform_args())
def test_waveform_refuses_what_it_cannot_build(tmp_path_factory, capsys, args):
    d = tmp_path_factory.mktemp("w")
    argv = ["waveform", "--out", str(d / "w.csv"), *args]
    code, _ = run(argv, capsys)
    if code == 0:
        _, cols, _ = read_columns(d / "w.csv")
        u = cols["u_nm"]
        assert np.all(np.isfinite(u)) and np.max(np.abs(u)) <= 2500.0 and u.size >= 10


@FUZZ
@given(
    center=st.tuples(number(-3000, 3000, "0"), number(-3000, 3000, "0")),
    size=number(1, 6000, "300"), pixels=st.one_of(st.just("32"), nasty_int),
    rate=number(0.01, 100, "2"),
)  # fmt: skip
def test_simulate_afm_refuses_before_building(tmp_path_factory, capsys, center, size, pixels,
                                             rate):  # fmt: skip
    d = tmp_path_factory.mktemp("a") / "out"
    try:
        small = int(pixels) <= 64
    except ValueError:
        small = True
    if not small and not (pixels.isdigit() and int(pixels) > 10**5):
        pixels = "32"  # keep the successful runs small; huge ones must be refused at once
    argv = ["simulate-afm", "--out", str(d), "--center-nm", *center, "--size-nm", size,
            "--pixels", pixels, "--line-rate-hz", rate]  # fmt: skip
    code, _ = run(argv, capsys)
    if code == 0:
        assert (d / "image.npz").exists()
    else:
        assert not d.exists()  # a failed run leaves no folder behind


@FUZZ
@given(span=number(10, 1e4, "6000"), speed=number(1, 1e5, "250"), period=number(1e-4, 10, "0.008"))
def test_identify_refuses_impossible_settings_at_once(tmp_path_factory, capsys, span, speed,
                                                      period):  # fmt: skip
    try:
        s, v, p = float(span), float(speed), float(period)
        # the ramps are capped at the scanner's slew limit (20 um/s)
        feasible = (
            math.isfinite(s) and math.isfinite(v) and math.isfinite(p)
            and 0 < s <= 5000 and 0 < v and 0 < p and s / (min(v, 20000.0) * p) >= 10
        )  # fmt: skip
    except ValueError:
        feasible = False
    if feasible:
        return  # a real identification: not a fuzzing matter (tests of its own)
    d = tmp_path_factory.mktemp("i") / "out"
    argv = ["identify", "--out", str(d), "--span-nm", span, "--speed-nm-per-s", speed,
            "--sample-period-s", period, "--no-figures"]  # fmt: skip
    code, _ = run(argv, capsys)
    assert code == 2
    assert not d.exists()
