"""Sensorless identification of the scanner model (Secs. III.C, IV).

A pipeline in stages: :mod:`.settings` (the user's) and :mod:`.config` (every setting),
:mod:`.recording` (acquisition), :mod:`.loop_fit` (Sec. IV, eqs 21-23), :mod:`.estimation`
(RLS of eqs 16-20, batch refinement, orders), :mod:`.scaling` (the calibration grating),
:mod:`.sensorless` (one axis end to end) and :mod:`.result`; :mod:`.offline` for a record
made with any instrument. With a position sensor, :mod:`piezocomp.sensor` fits the model to
the measured extension instead.

Works through :class:`piezocomp.instrument.Instrument` only: may import the core,
:mod:`piezocomp.io` and :mod:`piezocomp.imaging`; never the virtual AFM or experiments (the
virtual lab and the scoring on its truth are in :mod:`piezocomp.experiments`).
"""
