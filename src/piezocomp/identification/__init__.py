"""Sensorless identification of the scanner model (Secs. III.C-V): a pipeline of four stages,
each a sub-package with its own settings (its ``config`` module) and typed results, each
reading its own settings and the results of the stages before it. Three settings serve two
stages, as :mod:`.config` lists: the acquisition's peak prominence (read by the loop fit
too), the loop's degree (the acquisition chooses a line crossing enough particles for it) and the
acquisition's calibration cycles (from which the reference stage's frame is found, before
the estimation runs).

1. :mod:`.acquisition` (Sec. V, steps 1-2): the waveform of Fig. 7a, the line chosen in an
   overview, settled on and followed, the particle peaks, the record, calibration cycles and
   further lines -> :class:`~.acquisition.recording.AxisRecords`;
2. :mod:`.loop` (Sec. IV, eqs 21-23): the steady loop ``f_a`` and the topography ``h(y)``
   -> :class:`~.loop.fit.LoopEstimate`;
3. :mod:`.estimation` (Sec. III.C): RLS (eqs 16-20) and batch refinement of every candidate
   order, the orders chosen on held-out heights, several lines, the sample's drift along the
   line (:class:`~.estimation.problem.EstimationProblem`) ->
   :class:`~.estimation.chain.Estimation`;
4. :mod:`.reference`: the calibration frame the models are mapped onto
   (:class:`~.reference.frames.CalibrationFrame`), a calibration grating of known pitch and
   the models' scale -> :class:`~.reference.scaling.ScaleFit`.

Above them the pipeline: :mod:`.config` (:class:`~.config.IdentifyConfig`, the stages'
settings nested, read and written as TOML), :mod:`.sensorless` (one axis end to end,
:func:`~.sensorless.identify_axis` on an instrument, :func:`~.sensorless.estimate_axis` on
records), :mod:`.result` (:class:`~.result.AxisIdentification` and its ``summary()``),
:mod:`.offline` (a record made with any instrument) and :mod:`.planning` (the instrument
time before it runs). The compiled kernels the loop's ``h(y)`` and the RLS share are
``_rls_kernel``. This is drift as a disturbance of the identification;
:mod:`piezocomp.drift` compensates it during work. With a position sensor,
:mod:`piezocomp.sensor` fits the model to the measured extension instead.

The identification record (Fig. 7a, :mod:`.acquisition.waveforms`) has two parts: *part A*,
steady full cycles over the working span, from which the loop stage reads the loop and
``h(y)``; *part B*, cycles of decreasing amplitude then random minor loops with dwells. The
estimation stage fits the model to the record after a warm-up cycle, part B's last quarter
held out to choose the orders.

Names that mean more than one thing here (each follows the paper or the field where it is used):

- ``h``: the topography ``h(y)`` along the line (the loop stage's profile, Section IV), also
  the output map of the batch refinement's cost (``h(y)`` without a sensor, the identity
  with one); in the loop's own formulas ``h`` is the half-width of the command interval,
  ``(u_max - u_min) / 2`` (eq 23's normalisation);
- ``alpha``, ``beta`` of a frame map (:mod:`.reference.frames`): the gain and offset of
  ``Y = alpha y + beta`` between two frames of the extension, and ``alpha`` of a
  :class:`~.reference.scaling.ScaleFit` the grating's scale, ``P / Lambda / cos(angle)``
  (pitch over the period measured in the model's lengths, the grating's angle to the axis);
  the creep coupling of the extended family (eq 2') is ``beta`` too: ``creep_coupling`` on
  the model, ``beta`` (its free group ``"b"``) in the estimators; ``alpha`` of
  :class:`~.estimation.rls.RLSSettings` chooses eq (20)'s gain ``alpha(k)`` (``"paper"`` or
  ``"unit"``);
- ``P``: the RLS covariance in the estimation stage (of the free parameters, scaled; reset
  to ``p0 I``, Section III.C; the lower-case ``p_i`` are the creep poles); the polynomial
  ``P(s)`` of the loop's ascending branch (eq 23) in the loop stage; the grating's pitch in
  the reference stage (``pitch_nm`` in code);
- "calibration": the *calibration condition* of Section IV, ``f_a(u_max) - f_a(u_min) =
  u_max - u_min`` (the loop a model is indexed on fixes its scale); the *calibration
  cycles* (steady cycles over the span ``calibrate`` gives, by default the full range, at
  the calibration record's speed, recorded after the identification record; their loop is
  the *calibration frame* the models are mapped onto,
  :class:`~.reference.frames.CalibrationFrame`, found before the estimation runs and applied
  to its models after it); the *calibration record* (the scan under which the instrument's
  nominal sensitivity holds, its speed stated by the instrument or measured on a grating,
  :mod:`.reference.calibration_scan`, ``piezocomp calibrate``); a virtual scanner preset's
  own calibration (how ``cpr5`` was made, :mod:`piezocomp.virtual_afm`) is none of these.
  ``calibrate`` is the setting of :class:`~.acquisition.config.AcquisitionConfig` that
  chooses the calibration cycles' span (``"span"``: none, the working span's condition);
- a *grating* serves twice, each time a grating of known pitch mounted with the same
  scanner: the length reference (a "calibration grating" in the field's words) that gives
  the models' scale
  (:mod:`.reference.grating`, :mod:`.reference.scaling`) and, on an instrument that does not
  state its calibration record, the grating the record's speed is measured on
  (:mod:`.reference.calibration_scan`);
- "drift" is the sample's drift in four places: *across* the line during the record
  (:mod:`.acquisition.drift_across_line`, followed by :mod:`.acquisition.following`),
  *along* the line (:mod:`.estimation.drift_along_line`, taken out by
  :mod:`.estimation.drift_rounds`), between the grating's lines (its angle,
  :mod:`.reference.grating_angle`), and during work (:mod:`piezocomp.drift`, not here);
- *settling* on a line (scanning it in part A's steady cycle until the slow axis' creep after
  the moves onto it has slowed, before the record) is run by
  :mod:`.acquisition.line_search` (with the search onto the line: both are what the
  instrument does between the overview and the record); its cycles are dithered across the
  line (``cross_dither_nm``) so that :mod:`.acquisition.drift_across_line` can measure the
  drift across it on the same record.

Works through :class:`piezocomp.instrument.Instrument` only: may import the core and
:mod:`piezocomp.io`; never :mod:`piezocomp.imaging` (which imports its loop fit), the
virtual AFM or experiments (the virtual lab and the scoring on its truth are in
:mod:`piezocomp.experiments`).
"""
