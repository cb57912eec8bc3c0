"""Length reference, the record: a grating of known pitch scanned with the same scanner (the
scale it gives each model is :mod:`~piezocomp.identification.reference.scaling`'s).

Section IV fixes the loop by its symmetry and the calibration condition
``f_a(u_max) - f_a(u_min) = u_max - u_min``; both hold as well for any smooth odd change of
the length scale that keeps the ends, so particles alone leave the slope inside the span
free, and the topography of the identification record cannot see it either (``h``
re-indexes with the model). On the virtual ``cpr5`` scanner that freedom is a 0.5-2.4 %
scale error over +-500 nm, 2-7 nm at the ends of the span.

AFM practice fixes lengths with a grating of certified pitch. :func:`measure_grating`
scans steady cycles over the working span across a grating whose lines are perpendicular
to the axis (on a real instrument: after mounting the grating; the scanner is the same);
:class:`GratingRecord` holds them, and :mod:`~piezocomp.identification.reference.scaling` finds the
model's scale from it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.identification.acquisition.line_search import axis_command
from piezocomp.identification.acquisition.waveforms import identification_waveform, ramps
from piezocomp.instrument import Instrument

__all__ = [
    "GRATING_PATHS",
    "MAX_REST_S",
    "MINOR_TURNS",
    "MIN_PASS_PITCHES",
    "PATH_SEED",
    "SWEEP_FRACTION",
    "GratingRecord",
    "grating_path_for",
    "measure_grating",
    "minor_loop_path",
    "sweep_passes",
]


@dataclass(frozen=True)
class GratingRecord:
    """Steady cycles over a grating of known pitch, one axis.

    Attributes
    ----------
    axis : {"x", "y"}
    pitch_nm : float
        Certified pitch of the grating (nm).
    u_nm : ndarray
        Command of the axis, one sample per ``sample_period_s``, from rest (the scanner held
        at ``u_nm[0]`` for longer than its creep, e.g. after the sample exchange; if not,
        the cycles skipped before the first pass absorb most of it).
    height_nm : ndarray
        Measured heights, same length.
    sample_period_s : float
    passes : tuple of (int, int)
        ``[start, stop)`` sample ranges of the passes used for the fit (each a monotone ramp
        over the span; forward and backward in equal numbers).
    pass_lines : tuple of int
        The scan line of each pass (``0 .. n_lines - 1``); default all on line 0.
    line_slow_nm : tuple of float, optional
        Command of the other axis on each line (by line number). With two lines or more
        it lets :func:`fit_scale` measure the grating's angle and correct the pitch seen
        along the axis; ``None``: the grating is taken as square to the axis.
    measured_in_run : bool
        Whether :func:`measure_grating` made it in this run, so that its duration is part
        of the identification's instrument time (a record read from a file was made
        earlier).
    """

    axis: str
    pitch_nm: float
    u_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    sample_period_s: float
    passes: tuple[tuple[int, int], ...]
    pass_lines: tuple[int, ...] | None = None
    line_slow_nm: tuple[float, ...] | None = None
    measured_in_run: bool = False

    def __post_init__(self) -> None:
        if self.axis not in ("x", "y"):
            raise ValueError(f"axis must be 'x' or 'y'. Got {self.axis!r}.")
        p = check_finite_scalar("pitch_nm", self.pitch_nm)
        T = check_finite_scalar("sample_period_s", self.sample_period_s)
        if p <= 0 or T <= 0:
            raise ValueError(f"pitch_nm and sample_period_s must be > 0. Got {p}, {T}.")
        u = as_finite_array("u_nm", self.u_nm, ndim=1)
        z = as_finite_array("height_nm", self.height_nm, ndim=1)
        if u.shape != z.shape:
            raise ValueError(f"u_nm and height_nm must have one length. Got {u.size}, {z.size}.")
        passes = tuple((int(a), int(b)) for a, b in self.passes)
        if len(passes) < 2:
            raise ValueError(f"a grating record needs >= 2 passes. Got {len(passes)}.")
        for a, b in passes:
            if not 0 <= a < b - 8 <= u.size - 8:
                raise ValueError(f"pass [{a}, {b}) must lie in [0, {u.size}) and hold > 8 samples.")
        object.__setattr__(self, "pitch_nm", p)
        object.__setattr__(self, "sample_period_s", T)
        object.__setattr__(self, "u_nm", readonly(u))
        object.__setattr__(self, "height_nm", readonly(z))
        object.__setattr__(self, "passes", passes)
        lines = (0,) * len(passes) if self.pass_lines is None else tuple(self.pass_lines)
        if len(lines) != len(passes) or any(
            isinstance(v, bool) or int(v) != v or v < 0 for v in lines
        ):
            raise ValueError(
                f"pass_lines must hold one integer >= 0 per pass ({len(passes)}). Got {lines!r}."
            )
        object.__setattr__(self, "pass_lines", tuple(int(v) for v in lines))
        if self.line_slow_nm is not None:
            slow = tuple(
                check_finite_scalar(f"line_slow_nm[{i}]", v)
                for i, v in enumerate(self.line_slow_nm)
            )
            if len(slow) <= max(lines):
                raise ValueError(
                    f"line_slow_nm must hold the slow command of every line ({max(lines) + 1}). "
                    f"Got {len(slow)}."
                )
            object.__setattr__(self, "line_slow_nm", slow)

    @property
    def duration_s(self) -> float:
        """Instrument time of the record (its moves between lines included), s."""
        return float(self.u_nm.size * self.sample_period_s)

    @property
    def n_lines(self) -> int:
        """Number of distinct scan lines."""
        return len(set(self.pass_lines or (0,)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content (for saving a reference measured on a real instrument)."""
        return {
            "axis": self.axis,
            "pitch_nm": self.pitch_nm,
            "sample_period_s": self.sample_period_s,
            "passes": [list(p) for p in self.passes],
            "pass_lines": list(self.pass_lines or ()),
            "line_slow_nm": None if self.line_slow_nm is None else list(self.line_slow_nm),
            "u_nm": self.u_nm.tolist(),
            "height_nm": self.height_nm.tolist(),
        }

    @classmethod
    def from_dict(cls, body: Any, where: str = "grating record") -> GratingRecord:
        """Inverse of :meth:`to_dict`, with a clear error for a missing or malformed key."""
        keys = {
            "axis", "pitch_nm", "sample_period_s", "passes", "pass_lines", "line_slow_nm",
            "u_nm", "height_nm",
        }  # fmt: skip
        if not isinstance(body, dict) or set(body) != keys:
            got = sorted(body) if isinstance(body, dict) else type(body).__name__
            raise ValueError(f"{where} must hold exactly the keys {sorted(keys)}. Got {got}.")
        try:
            return cls(
                axis=body["axis"],
                pitch_nm=body["pitch_nm"],
                u_nm=np.asarray(body["u_nm"], dtype=float),
                height_nm=np.asarray(body["height_nm"], dtype=float),
                sample_period_s=body["sample_period_s"],
                passes=tuple(tuple(p) for p in body["passes"]),
                pass_lines=tuple(body["pass_lines"]),
                line_slow_nm=None if body["line_slow_nm"] is None else tuple(body["line_slow_nm"]),
            )
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None


GRATING_PATHS = ("steady", "minor_loops")
"""What :func:`measure_grating` scans along the axis on each line."""

MIN_PASS_PITCHES = 3.0
"""The shortest sweep of the minor-loop path, in pitches of command: at least two periods
in the scanner's lengths where it moves 70 % of the nominal distance."""

SWEEP_FRACTION = 0.7
"""The minor-loop path's sweeps run from the outer 15 % of the span at one end to the outer
15 % at the other: at least this fraction of the span."""

MINOR_TURNS = 3
"""Random minor reversals (2-30 % of the span, log-uniform) before each sweep of the
minor-loop path."""

MAX_REST_S = 3.0
"""Longest rest at a turning point of the minor-loop path (half of them rest, uniform up to
this)."""

PATH_SEED = 1000
"""The minor-loop path's draw on line ``i`` is ``PATH_SEED + i`` (a fixed path, the same on
every run)."""


def minor_loop_path(
    center_nm: float,
    span_nm: float,
    speed_nm_per_s: float,
    sample_period_s: float,
    *,
    n_sweeps: int = 4,
    rng: int = PATH_SEED,
) -> NDArray[np.float64]:
    """One line's command for the minor-loop grating path.

    From the low end of ``center +- span/2``: ``n_sweeps`` times, :data:`MINOR_TURNS` random
    minor reversals in the half of the span the tip is in (log-uniform 2-30 % of the span),
    a move to a random point in that end's outer 15 %, then a sweep to a random point in the
    outer 15 % of the other end; half the turning points rest (uniform up to
    :data:`MAX_REST_S`). The sweeps alternate in direction and each spans
    :data:`SWEEP_FRACTION` of the span or more; the history before each is a path of the
    kind positioning takes (moves of every size, rests), so the scale the grating gives is
    the one those paths see.
    """
    if (
        isinstance(n_sweeps, bool)
        or not isinstance(n_sweeps, int | np.integer)
        or n_sweeps < 2
        or n_sweeps % 2
    ):
        raise ValueError(f"n_sweeps must be an even integer >= 2. Got {n_sweeps!r}.")
    gen = np.random.default_rng(rng)
    lo, hi = center_nm - 0.5 * span_nm, center_nm + 0.5 * span_nm
    edge = 0.5 * (1.0 - SWEEP_FRACTION) * span_nm
    tps, dwells = [lo], [0.0]

    def rest() -> float:
        return float(gen.uniform(0.0, MAX_REST_S)) if gen.random() < 0.5 else 0.0

    for j in range(int(n_sweeps)):
        a, b = (lo, center_nm) if j % 2 == 0 else (center_nm, hi)  # the near half
        for _ in range(MINOR_TURNS):
            prev = tps[-1]
            size = span_nm * float(np.exp(gen.uniform(np.log(0.02), np.log(0.3))))
            up = prev - size < a or (prev + size <= b and gen.random() < 0.5)
            tps.append(min(max(prev + size if up else prev - size, a), b))
            dwells.append(rest())
        near = lo + edge * float(gen.random()) if j % 2 == 0 else hi - edge * float(gen.random())
        far = hi - edge * float(gen.random()) if j % 2 == 0 else lo + edge * float(gen.random())
        tps += [near, far]
        dwells += [rest(), rest()]
    return ramps(tps, speed_nm_per_s, sample_period_s, dwells)


def grating_path_for(span_nm: float, pitch_nm: float, path: str = "auto") -> str:
    """The grating path to scan: ``path`` itself, or for ``"auto"`` the minor loops where
    :data:`SWEEP_FRACTION` of the span holds :data:`MIN_PASS_PITCHES` pitches, else the
    steady cycles."""
    if path != "auto":
        return path
    return "minor_loops" if SWEEP_FRACTION * span_nm >= MIN_PASS_PITCHES * pitch_nm else "steady"


def sweep_passes(u_nm: NDArray[np.float64], span_nm: float) -> list[tuple[int, int]]:
    """The passes of a minor-loop line (:func:`minor_loop_path`): ``[start, stop)`` of its
    monotone stretches spanning :data:`SWEEP_FRACTION` of ``span_nm`` or more, as many rising
    as falling (the first of each, in time), so that drift's first-order stretch cancels
    between the two directions."""
    u = np.asarray(u_nm, dtype=float)
    step = np.diff(u)
    moving = step != 0
    sign = np.sign(step)
    # a stretch: consecutive moving steps of one sign
    edges = np.flatnonzero(np.diff(np.r_[0, np.where(moving, sign, 0), 0]) != 0)
    up: list[tuple[int, int]] = []
    down: list[tuple[int, int]] = []
    for a, b in itertools.pairwise(edges):
        if not moving[a] or abs(float(u[b] - u[a])) < SWEEP_FRACTION * span_nm:
            continue
        (up if sign[a] > 0 else down).append((int(a), int(b) + 1))
    n = min(len(up), len(down))
    return sorted(up[:n] + down[:n])


def _slow_lines(
    range_nm: float,
    center_slow_nm: float,
    n_lines: int,
    line_spacing_nm: float | None,
    angle_line_offset_nm: float | None,
) -> list[float]:
    """Where on the other axis :func:`measure_grating` scans its lines (see there): checked
    to lie in the range before anything moves."""
    c_slow = check_finite_scalar("center_nm", center_slow_nm)
    half = 0.5 * range_nm
    if line_spacing_nm is None:
        room = 0.9 * half - abs(c_slow)
        spacing = min(1000.0, room / max(0.5 * (n_lines - 1), 1.0))
    else:
        spacing = check_finite_scalar("line_spacing_nm", line_spacing_nm)
    offsets = [spacing * (i - 0.5 * (n_lines - 1)) for i in range(int(n_lines))]
    if angle_line_offset_nm is not None and n_lines >= 2:
        d = check_finite_scalar("angle_line_offset_nm", angle_line_offset_nm)
        if d == 0 or any(abs(o - (offsets[n_lines // 2] + d)) < 1e-6 for o in offsets):
            raise ValueError(
                f"angle_line_offset_nm must put a line where none is. Got {d} with lines at "
                f"{offsets} nm from the centre."
            )
        offsets = sorted([*offsets, offsets[n_lines // 2] + d])
    slow_lines = [c_slow + o for o in offsets]
    outside = [v for v in slow_lines if abs(v) > half]
    if outside:
        raise ValueError(
            f"grating lines at {outside} nm on the other axis lie outside its range "
            f"(+-{half:g} nm): give a smaller line_spacing_nm (got {spacing:g}) or fewer lines."
        )
    return slow_lines


def measure_grating(
    instrument: Instrument,
    pitch_nm: float,
    *,
    axis: str = "x",
    center_nm: tuple[float, float] = (0.0, 0.0),
    span_nm: float = 1000.0,
    speed_nm_per_s: float = 250.0,
    n_cycles: int = 6,
    skip_cycles: int = 2,
    n_lines: int = 5,
    line_spacing_nm: float | None = None,
    angle_line_offset_nm: float | None = 100.0,
    path: str = "steady",
    n_sweeps: int = 4,
) -> GratingRecord:
    """Scan cycles over ``center +- span/2`` along ``axis`` across a grating.

    The grating's lines must run perpendicular to ``axis`` (along the other axis). Use the
    span, centre and speed of the identification, so the scale is measured where the model
    was fitted. ``n_lines`` scan lines, ``line_spacing_nm`` apart on the other axis and
    centred on ``center_nm``, each get ``n_cycles`` steady cycles, the first
    ``skip_cycles`` of which settle the loop and are not used. Several lines average out
    what a single line's heights add to the grating's (substrate roughness, defects). They
    only do so if they are farther apart than the roughness is long: on the virtual
    ``cpr5`` sample (roughness 30-600 nm long) one line's scale scatters by 0.03-0.1 %, and
    five lines 100 nm apart left 0.05 % (rms over seeds 1-8) against 0.017 % 1000 nm apart.

    ``line_spacing_nm`` defaults to 1000 nm, or less where the other axis' range does not
    hold the lines (90 % of it). With two lines or more and ``angle_line_offset_nm``, one
    more line is scanned that far from the centre line: that close pair measures the
    grating's angle without the ambiguity of one period that lines far apart leave
    (:func:`fit_scale`), and its passes count in the scale like any other's. ``None`` scans
    no such line.

    ``path`` is what each line's scan does along the axis: ``"steady"``, ``n_cycles`` full
    cycles (as above); ``"minor_loops"``, ``n_sweeps`` long sweeps across the span
    alternating in direction, each after random minor loops and rests where it starts
    (:func:`minor_loop_path`, a fixed draw per line): the sweeps are the passes. A model's
    scale error depends on the path: the grating gives the scale on the path it is scanned
    along, and the minor loops' is nearer the one positioning needs, in about half the
    steady path's time (``benchmarks/grating_scale.py`` measures both; it needs a span of
    :data:`MIN_PASS_PITCHES` pitches in :data:`SWEEP_FRACTION` of it).

    The record holds every command of the axis from the first move on (the moves between
    lines included), so a model runs over it continuously; it starts one step from where
    the instrument rested.

    Returns
    -------
    GratingRecord
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    pitch = check_finite_scalar("pitch_nm", pitch_nm)
    if pitch <= 0:  # checked before anything moves
        raise ValueError(f"pitch_nm must be > 0. Got {pitch}.")
    for name, v in (("n_cycles", n_cycles), ("skip_cycles", skip_cycles), ("n_lines", n_lines)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 0:
            raise ValueError(f"{name} must be an integer >= 0. Got {v!r}.")
    if n_cycles - skip_cycles < 1:
        raise ValueError(f"n_cycles - skip_cycles must be >= 1. Got {n_cycles} - {skip_cycles}.")
    if n_lines < 1:
        raise ValueError(f"n_lines must be >= 1. Got {n_lines}.")
    if path not in GRATING_PATHS:
        raise ValueError(f"path must be one of {GRATING_PATHS}. Got {path!r}.")
    if path == "minor_loops" and grating_path_for(span_nm, pitch) != "minor_loops":
        raise ValueError(
            f"span_nm {span_nm:g} must hold {MIN_PASS_PITCHES:g} pitches ({pitch:g} nm) in "
            f"{SWEEP_FRACTION:.0%} of it for the minor-loop path's sweeps: scan a longer span, a "
            "finer grating, or path='steady'."
        )
    k = 0 if axis == "x" else 1
    slow_lines = _slow_lines(
        float(instrument.range_nm), center_nm[1 - k], n_lines, line_spacing_nm,
        angle_line_offset_nm,
    )  # fmt: skip
    T = float(instrument.sample_period_s)
    speed = min(
        check_finite_scalar("speed_nm_per_s", speed_nm_per_s), instrument.max_speed_nm_per_s
    )
    wf = identification_waveform(
        center_nm[k], span_nm, speed, T, n_steady=int(n_cycles), n_decaying=0, n_random=0
    )
    us: list[NDArray[np.float64]] = []
    zs: list[NDArray[np.float64]] = []
    passes = []
    lines: list[int] = []
    slows: list[float] = []
    n0 = 0
    for i, slow in enumerate(slow_lines):
        slows.append(slow)
        if path == "steady":
            u_line = wf.u_nm
            line_passes = [
                (int(sl.start), int(sl.stop))
                for c in range(int(skip_cycles), int(n_cycles))
                for sl in (wf.ascending(c), wf.descending(c))
            ]
        else:
            u_line = minor_loop_path(
                center_nm[k], span_nm, speed, T, n_sweeps=int(n_sweeps), rng=PATH_SEED + i
            )
            line_passes = sweep_passes(u_line, span_nm)
        start = (u_line[0], slow) if axis == "x" else (slow, u_line[0])
        move = instrument.move_to(start[0], start[1], speed)
        rec = instrument.run(axis_command(axis, u_line, slow))
        n0 += len(move)
        for a, b in line_passes:
            passes.append((n0 + a, n0 + b))
            lines.append(i)
        n0 += len(rec)
        us += [move.command_nm[:, k], rec.command_nm[:, k]]
        zs += [move.height_nm, rec.height_nm]
    return GratingRecord(
        axis=axis,
        pitch_nm=float(pitch_nm),
        u_nm=np.concatenate(us),
        height_nm=np.concatenate(zs),
        sample_period_s=T,
        passes=tuple(passes),
        pass_lines=tuple(lines),
        line_slow_nm=tuple(slows),
        measured_in_run=True,
    )
