"""Thermal drift: measured on landmarks, filtered, and compensated between moves.

The authors' earlier system (Mokaberi & Requicha, IEEE T-ASE 3(3), 2006), which the 2008
paper assumes runs alongside its creep-and-hysteresis compensator:

- :mod:`.filter`: the Kalman filter of drift (displacement, velocity and, by default,
  acceleration per axis), its noise
  estimated from a recorded run (:func:`fit_noise`); :mod:`.noise_learning`: that noise
  learnt again from the session's own measurements as it runs;
- :mod:`.landmarks`: landmark windows chosen, templated and sighted by cross-correlation;
- :mod:`.landmark_set`: the landmarks tracked, their replacements, and the wider search when
  the prediction has become too uncertain for their windows;
- :mod:`.schedule`: when the landmarks are measured (before a motion, between an image's
  lines or a wait's pieces);
- :mod:`.compensated`: :class:`DriftCompensatedInstrument`, an ``Instrument`` fixed to the
  drifting sample, composable with :class:`piezocomp.positioning.CompensatedInstrument`;
- :mod:`.scanner_error`: the error of a scanner without that compensator at the landmarks,
  measured, and what it sizes (``DriftSettings.uncompensated()``);
- :mod:`.state_file`: the saved tracking state;
- :mod:`.series`: drift measured on a series of images of one area (a drift movie).

May import the core and :mod:`piezocomp.imaging`; never the virtual AFM or experiments.
"""

from piezocomp.drift.compensated import DriftCompensatedInstrument
from piezocomp.drift.filter import DriftFilter, DriftNoise, DriftSettings, fit_noise

__all__ = ["DriftCompensatedInstrument", "DriftFilter", "DriftNoise", "DriftSettings", "fit_noise"]
