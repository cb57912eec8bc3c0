"""Stage 4, the length reference: a calibration grating of known pitch, scanned with the same
scanner, scales the models (particles cannot give the scale).

- :mod:`.config`: its settings, :class:`~.config.ReferenceConfig`;
- :mod:`.grating`: the grating's record, :func:`~.grating.measure_grating`;
- :mod:`.grating_angle`: the grating's angle to the axis;
- :mod:`.scaling`: each model's scale from the grating, :func:`~.scaling.scale_fits`.

Reads the earlier stages' results; the last stage.
"""
