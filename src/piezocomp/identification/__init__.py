"""Sensorless identification of the scanner model (Secs. III.C, IV).

A pipeline in stages, :mod:`.sensorless` running one axis end to end into a :mod:`.result`:

- settings: :mod:`.settings` (the user's), :mod:`.config` (every setting),
  :mod:`.estimation_options` (the estimation stage's), :mod:`.threads` (BLAS threads);
- acquisition (:mod:`.recording`): the command :mod:`.waveforms` (Fig. 7a); the line chosen
  in an overview (:mod:`.line_choice`), settled and checked (:mod:`.acquisition`,
  :mod:`.diagnostics`); the line followed as the sample slides under it
  (:mod:`.following`); the instrument time of each step (:mod:`.instrument_time`);
- the loop (Sec. IV, eqs 21-23): :mod:`.peaks` on both traces, the steady :mod:`.loop`,
  its fit (:mod:`.loop_fit`, :mod:`.pi_loop`) and the frames of the extension
  (:mod:`.frames`);
- estimation (Sec. III.C): the topography :mod:`.profile` ``h(y)``, the model's
  :mod:`.prediction` of the record, the parameter vector of eq (15) (:mod:`.parameters`),
  the candidate models (:mod:`.candidates`), RLS of eqs 16-20 (:mod:`.rls`, its kernel),
  batch refinement (:mod:`.batch`, :mod:`.batch_cost`, :mod:`.reparametrisation`), the
  orders (:mod:`.orders`), several lines at once (:mod:`.lines`) and the stage itself
  (:mod:`.estimation`), with :mod:`.findings` on models gone astray;
- the sample's drift during the record, taken out of the estimation: along the line
  (:mod:`.line_drift`, :mod:`.drift_rounds`) and across it (:mod:`.cross_drift`); this is
  drift as a disturbance of the identification, :mod:`piezocomp.drift` compensates it
  during work;
- the length reference: the grating record (:mod:`.reference`), its angle
  (:mod:`.grating_angle`) and the scale (:mod:`.scaling`);
- :mod:`.offline` for a record made with any instrument.

With a position sensor, :mod:`piezocomp.sensor` fits the model to the measured extension
instead.

Works through :class:`piezocomp.instrument.Instrument` only: may import the core and
:mod:`piezocomp.io`; never :mod:`piezocomp.imaging` (which imports its loop fit), the
virtual AFM or experiments (the virtual lab and the scoring on its truth are in
:mod:`piezocomp.experiments`).
"""
