"""The result of the identification of one axis: the stages' outputs, nested, fixed shape.

:class:`AxisIdentification` holds what each stage of the pipeline
(:mod:`~piezocomp.identification.sensorless`) produced: the records, the loop, the
estimation, the frame maps and scales, the models, the findings and the timings. Its
properties give the parts the figures and the scoring read by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.instrument_time import with_total
from piezocomp.identification.acquisition.line_choice import LineChoice
from piezocomp.identification.acquisition.line_search import LineStability
from piezocomp.identification.acquisition.recording import AxisRecords
from piezocomp.identification.acquisition.waveforms import IdentificationWaveform
from piezocomp.identification.estimation.batch import RefineResult
from piezocomp.identification.estimation.chain import Estimation, far_worse
from piezocomp.identification.estimation.findings import BATCH_ASTRAY_RATIO, POOR_HELDOUT_NM
from piezocomp.identification.estimation.orders import OrderSelection
from piezocomp.identification.estimation.prediction import record_state
from piezocomp.identification.estimation.rls import RLSResult
from piezocomp.identification.loop.fit import LoopEstimate
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.reference.frames import FrameMap, unmapped
from piezocomp.identification.reference.grating import GratingRecord
from piezocomp.identification.reference.scaling import ScaleFit
from piezocomp.instrument import ScanImage
from piezocomp.model import ModelState, ScannerModel, ScannerModel2D, simulate

__all__ = ["AxisIdentification", "FrameMap", "Identification"]


@dataclass(frozen=True)
class AxisIdentification:
    """Everything the identification of one axis produced, stage by stage.

    Attributes
    ----------
    records : AxisRecords
        What the instrument returned (stage 1).
    loop : LoopEstimate
        Section IV on the working span (part A): ``f_a`` and ``h(y)``.
    calibration : LoopEstimate or None
        Section IV on the calibration cycles, if they were run and could be used.
    estimation : Estimation
        The orders tried and chosen, the RLS and batch estimates in the working frame, their
        held-out height RMS.
    fit_mask : ndarray of bool
        Samples of the record used for fitting (the rest held out).
    creep_start_nm : float or None
        Creep states the estimation assumed before the record (:meth:`initial_state`).
    frame_maps : dict of str to (float, float)
        ``"rls"`` and ``"batch"``: the map from each estimate's working frame to the model
        returned (calibration frame, grating scale).
    models : dict of str to ScannerModel
        ``"rls"`` and ``"batch"``: the models to compensate with.
    reference : dict of str to ScaleFit, or None
        The grating's scale of each model, with a grating record.
    unreferenced_models : dict of str to ScannerModel, or None
        The models before the grating's scale (for comparison).
    reference_record : GratingRecord or None
    rls_on_lines : bool
        Whether the RLS estimate is the one run on every line.
    final_fit : bool
        Whether the models were fitted over the whole record at the end (the held-out
        figures are then those of the models before it).
    findings : tuple of str
        What a user should read (also issued as :class:`ExcitationWarning`).
    timing_s : dict
        Time spent in each stage.
    line_drift : dict or None
        The sample's drift along the line during the records, estimated with the model
        (:mod:`~piezocomp.identification.estimation.drift_along_line`): ``kept`` (taken out of the
        models), the first line's ``rate_nm_per_s`` and ``extent_nm``, each line's path (``lines``),
        and the held-out height RMS of the batch model estimated without it and with it
        (``heldout_rms_without_nm``, ``heldout_rms_with_nm``); ``None`` when not estimated.
    """

    records: AxisRecords
    loop: LoopEstimate
    calibration: LoopEstimate | None
    estimation: Estimation
    fit_mask: NDArray[np.bool_]
    creep_start_nm: float | None
    frame_maps: dict[str, FrameMap]
    models: dict[str, ScannerModel]
    reference: dict[str, ScaleFit] | None
    unreferenced_models: dict[str, ScannerModel] | None
    reference_record: GratingRecord | None
    rls_on_lines: bool
    final_fit: bool
    findings: tuple[str, ...]
    timing_s: dict[str, float]
    line_drift: dict[str, Any] | None = None

    # the records' and the estimation's parts, by the names the figures and scoring use
    @property
    def instrument_s(self) -> dict[str, float]:
        """Instrument time of each stage, s: the acquisition's
        (:attr:`~piezocomp.identification.acquisition.recording.AxisRecords.instrument_s`) and the
        grating's record (``"grating"``) when it was measured in this run; empty for a
        recorded run."""
        out = dict(self.records.instrument_s)
        ref = self.reference_record
        if ref is not None and ref.measured_in_run:
            out["grating"] = ref.duration_s
        return out

    @property
    def axis(self) -> str:
        return self.records.axis

    @property
    def waveform(self) -> IdentificationWaveform:
        return self.records.waveform

    @property
    def u_nm(self) -> NDArray[np.float64]:
        """The identification record's command of the axis."""
        return self.records.u_nm

    @property
    def height_nm(self) -> NDArray[np.float64]:
        """The identification record's measured heights."""
        return self.records.height_nm

    @property
    def sample_period_s(self) -> float:
        return self.records.sample_period_s

    @property
    def history_u_nm(self) -> NDArray[np.float64]:
        """Every command of the axis from the record on (for continuing a model)."""
        return self.records.history_u_nm

    @property
    def line(self) -> LineChoice | None:
        """The line recorded (``None`` for a recorded run)."""
        return self.records.line

    @property
    def cross_drift(self) -> dict[str, Any] | None:
        """The line's slide across its particles measured while the tip settled, and whether the
        record followed it
        (:class:`~piezocomp.identification.acquisition.drift_across_line.CrossDrift` summary;
        ``None`` when not measured)."""
        c = self.records.cross_drift
        return None if c is None else c.summary()

    @property
    def overview(self) -> ScanImage | None:
        return self.records.overview

    @property
    def line_stability(self) -> LineStability | None:
        return self.records.line_stability

    @property
    def extra_lines(self) -> tuple[LineChoice, ...]:
        """The further lines, ``slow_nm`` where they were recorded."""
        return tuple(e.line for e in self.records.extra)

    @property
    def profile(self) -> HeightProfile:
        """The loop's ``h(y)`` (Section IV)."""
        return self.loop.profile

    @property
    def orders(self) -> OrderSelection:
        return self.estimation.selection

    @property
    def rls(self) -> RLSResult:
        """The RLS of the chosen orders (Fig. 7b traces), in the working frame."""
        return self.estimation.rls

    @property
    def refine(self) -> RefineResult | None:
        return self.estimation.refine

    @property
    def rls_model(self) -> ScannerModel:
        return self.models["rls"]

    @property
    def batch_model(self) -> ScannerModel:
        return self.models["batch"]

    @property
    def frame_map(self) -> FrameMap:
        """The batch model's frame map."""
        return self.frame_maps["batch"]

    @property
    def rls_frame_map(self) -> FrameMap:
        return self.frame_maps["rls"]

    @property
    def batch_profile(self) -> HeightProfile:
        """The ``h(y)`` the batch model was refined with."""
        return self.estimation.batch_profile

    @property
    def rls_profile(self) -> HeightProfile:
        """The ``h(y)`` of the RLS estimate."""
        return self.estimation.rls_profile

    @property
    def heldout_rms_nm(self) -> dict[str, float]:
        """Held-out height RMS (nm) of ``"initial"``, ``"rls"`` and ``"batch"``."""
        return dict(self.estimation.heldout_rms_nm)

    @property
    def batch_restart(self) -> dict[str, Any] | None:
        return self.estimation.batch_restart

    def validation_failures(self) -> list[str]:
        """Why the batch model (the one to compensate with) fails its own validation, read
        from the record alone (no ground truth): its held-out heights predicted worse than
        :data:`~piezocomp.identification.estimation.findings.POOR_HELDOUT_NM`, or far worse than the
        RLS estimate's (:data:`~piezocomp.identification.estimation.findings.BATCH_ASTRAY_RATIO`).
        The grating's scale is checked against the calibration cycles when it is fitted (a
        disagreement raises there). Empty when the model may be used."""
        held = self.heldout_rms_nm
        b, r = held.get("batch", float("nan")), held.get("rls", float("nan"))
        out = []
        if not b <= POOR_HELDOUT_NM:
            out.append(
                f"held-out heights predicted to {b:.2f} nm RMS (at most {POOR_HELDOUT_NM:g})"
            )
        if far_worse(b, r, BATCH_ASTRAY_RATIO):
            out.append(f"held-out heights {b:.2f} nm RMS, far worse than the RLS's {r:.2f} nm")
        return out

    def initial_state(self, model: ScannerModel) -> ModelState:
        """The state the estimation assumed before the record's first sample (any frame):
        play operators at rest at the first command, creep states at ``creep_start_nm``."""
        return record_state(model, float(self.u_nm[0]), self.creep_start_nm)

    def predict_heights(
        self, model: ScannerModel, profile: HeightProfile | None = None
    ) -> NDArray[np.float64]:
        """``h(y_hat)`` of a working-frame model over the record (eqs 14, 16), through
        ``profile`` (default the loop's)."""
        y, _ = simulate(model, self.u_nm, self.sample_period_s, self.initial_state(model))
        return np.asarray((self.profile if profile is None else profile)(y))

    def working_models(self) -> dict[str, tuple[ScannerModel, HeightProfile]]:
        """The RLS and batch models in their working frames, each with its ``h(y)``."""
        return {
            "rls": (unmapped(self.rls_model, *self.rls_frame_map), self.rls_profile),
            "batch": (unmapped(self.batch_model, *self.frame_map), self.batch_profile),
        }

    def summary(self) -> dict[str, Any]:
        """What the identification of the axis found, JSON-ready: ``summary.json``'s entry
        of the axis, whatever the record came from (virtual AFM, a recorded run, an
        instrument). Read from the records alone: the validation against a simulator's
        ground truth is the experiments' (:mod:`piezocomp.experiments.scoring`).

        Keys: ``line`` (the line's slow command and particles, ``None`` for a recorded run;
        the loop's pairs and degree; the particles' slide along the line while the tip
        settled, ``drift_nm_per_s``, and across it, ``cross_drift``), ``extra_lines``,
        ``line_drift``, ``reference`` (each model's grating scale), ``heldout_height_rms_nm``,
        ``heldout_before_final_fit``, ``orders`` (with every candidate's ``trials``),
        ``rls_orders``, ``creep_coupling`` (each model's ``beta`` of eq 2'), ``frame_map``
        and ``rls_frame_map`` (``alpha`` and ``beta_nm``: the frame's gain and offset),
        whether ``h`` was re-indexed by each model, ``rls_on_lines``, ``rls_reindex_round``,
        ``batch_restart``, ``line_check`` (the line's profile change over the record),
        ``rls_resets``, ``refine``, ``findings``, ``validation_failures`` (why the batch
        model may not be used: :meth:`validation_failures`), ``timing_s`` and
        ``instrument_s`` (by stage, with the ``total``).
        """
        line = self.line
        est = self.estimation
        stability = self.line_stability
        rls_map = self.rls_frame_map
        return {
            "extra_lines": [
                {"slow_nm": e.slow_nm, "particles": e.n_particles} for e in self.extra_lines
            ],
            "line": {
                "slow_nm": None if line is None else line.slow_nm,
                "particles": None if line is None else line.n_particles,
                "loop_pairs": int(sum(len(a) for a, _ in self.loop.all_pairs)),
                "loop_degree": self.loop.loop.degree,
                # the particles' slide along the line while settling: the sample's drift
                "drift_nm_per_s": self.records.drift_nm_per_s,
                # its slide across the particles (drift and slow-axis creep), followed or not
                "cross_drift": self.cross_drift,
            },
            # the sample's drift along the line during the records, estimated with the model,
            # and the held-out heights of the batch model estimated without it and with it
            "line_drift": self.line_drift,
            "reference": None
            if self.reference is None
            else {m: f.summary() for m, f in self.reference.items()},
            "heldout_height_rms_nm": self.heldout_rms_nm,
            # the models were then fitted over the whole record, held-out part included
            "heldout_before_final_fit": self.final_fit,
            "orders": {
                "n_play": self.orders.n_play,
                "n_creep": self.orders.n_creep,
                "trials": self.orders.table(),
            },
            "rls_orders": {"n_play": self.rls.model.n_play, "n_creep": self.rls.model.n_creep},
            # beta of eq (2'), the creep coupling of each model (the RLS's is the paper's, 0)
            "creep_coupling": {m: self.models[m].creep_coupling for m in ("batch", "rls")},
            "frame_map": {"alpha": self.frame_map[0], "beta_nm": self.frame_map[1]},
            "rls_frame_map": {"alpha": rls_map[0], "beta_nm": rls_map[1]},
            "batch_profile_reindexed": self.batch_profile is not None
            and self.batch_profile is not self.profile,
            "rls_profile_reindexed": self.rls_profile is not None
            and self.rls_profile is not self.profile,
            "rls_on_lines": self.rls_on_lines,
            # the round of re-indexing h by the RLS estimate kept (0: the loop's h)
            "rls_reindex_round": est.rls_round,
            # the batch chain run again from the RLS estimate when it ended far worse
            "batch_restart": self.batch_restart,
            # the line's profile change over the record (slow-axis creep across the line), which
            # every model's held-out heights carry; a finding only beyond CHECK_TOLERANCE_NM
            "line_check": None
            if stability is None
            else {
                "height_change_rms_nm": stability.height_change_rms_nm,
                "height_change_max_nm": stability.height_change_max_nm,
                "noise_rms_nm": stability.noise_rms_nm,
            },
            "rls_resets": int(self.rls.resets.size),
            "refine": None
            if self.refine is None
            else {
                "nfev": self.refine.nfev,
                "rms_nm": self.refine.rms,
                "message": self.refine.message,
            },
            "findings": list(self.findings),
            # why the batch model may not be used (empty: it may): the command then exits 1
            "validation_failures": self.validation_failures(),
            "timing_s": self.timing_s,
            "instrument_s": with_total(self.instrument_s),
        }


@dataclass(frozen=True)
class Identification:
    """The identification of one or both axes
    (:func:`~piezocomp.identification.sensorless.identify`).

    Parameters
    ----------
    axes : dict of str to AxisIdentification
        By axis, ``"x"`` and/or ``"y"``.
    """

    axes: dict[str, AxisIdentification]

    def __post_init__(self) -> None:
        if not self.axes or set(self.axes) - {"x", "y"}:
            raise ValueError(f"axes must be 'x' and/or 'y'. Got {sorted(self.axes)!r}.")

    def validation_failures(self) -> list[str]:
        """Why a model to compensate with fails its own validation, by axis (no ground truth:
        :meth:`AxisIdentification.validation_failures`). Empty when the models may be used."""
        return [f"axis {a}: {why}" for a, i in self.axes.items() for why in i.validation_failures()]

    def _models(self, attr: str) -> ScannerModel | ScannerModel2D:
        failed = self.validation_failures()
        if failed:
            raise ValueError(
                "the identified model fails its own validation, not to be used ("
                + "; ".join(failed)
                + "); its parts stay readable in .axes"
            )
        if len(self.axes) == 2:
            return ScannerModel2D(getattr(self.axes["x"], attr), getattr(self.axes["y"], attr))
        return getattr(next(iter(self.axes.values())), attr)  # type: ignore[no-any-return]

    @property
    def model(self) -> ScannerModel | ScannerModel2D:
        """The model to compensate with (the batch model; 2-D when both axes were identified).
        Refused with :class:`ValueError` when an axis fails its own validation."""
        return self._models("batch_model")

    @property
    def rls_model(self) -> ScannerModel | ScannerModel2D:
        """The RLS estimate of eqs (16)-(20), the same way (refused as :attr:`model` is)."""
        return self._models("rls_model")

    def summary(self) -> dict[str, Any]:
        """Each axis' :meth:`AxisIdentification.summary`, by axis (``summary.json``'s form)."""
        return {axis: ident.summary() for axis, ident in self.axes.items()}
