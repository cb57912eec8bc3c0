"""Stage 1, acquisition (Section V, steps 1-2): what the instrument is asked to do for one
axis, and what comes back, as :class:`~.recording.AxisRecords`.

- :mod:`.config`: its settings, :class:`~.config.AcquisitionConfig` (the working area, the
  overview, settling, the check of the line, calibration cycles, further lines, the peaks'
  prominence) with the waveform's, :class:`~.config.WaveformConfig`;
- :mod:`.waveforms`: the command of Fig. 7a (and the validation trajectories);
- :mod:`.peaks`: particle peaks in a height trace and their pairing across traces;
- :mod:`.line_choice`: the line crossing the most particles in an overview;
- :mod:`.line_search`: the overview, the search back onto the line, settling on it, its check;
- :mod:`.drift_across_line` and :mod:`.following`: the line's slide across its particles,
  followed by the slow axis during the record;
- :mod:`.recording`: the acquisition of one axis, :func:`~.recording.record_axis`;
- :mod:`.instrument_time`: the instrument time of each step;
- :mod:`.diagnostics`: whether the record excites the play operators.

Imports no later stage: it knows the loop's degree only as a number it is given.
"""
