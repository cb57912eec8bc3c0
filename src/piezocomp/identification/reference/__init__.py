"""Stage 4, the reference: the models put on the calibration frame (Section IV) and scaled by
a calibration grating of known pitch, scanned with the same scanner (particles cannot give
the scale).

- :mod:`.config`: its settings, :class:`~.config.ReferenceConfig`;
- :mod:`.calibration_scan`: the scanner's calibration record measured on a grating (the
  speed of the calibration cycles), :func:`~.calibration_scan.measure_calibration_scan`;
- :mod:`.frames`: the frames of the extension (the working loop's, the calibration cycles')
  and each model's map onto the calibration frame, :class:`~.frames.CalibrationFrame`;
- :mod:`.grating`: the grating's record, :func:`~.grating.measure_grating`;
- :mod:`.grating_angle`: the grating's angle to the axis;
- :mod:`.scaling`: each model's scale from the grating, :func:`~.scaling.scale_fits`.

Reads the earlier stages' results; the last stage. The calibration frame is found from the
calibration cycles' loop before the estimation runs and applied to its models after it.
"""
